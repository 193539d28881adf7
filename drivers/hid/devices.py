"""`gazehdr devices`: every HID interface hidapi enumerates, and whether gazehdr can use it.

Eye trackers (usage page 0x12) are opened to read their descriptor and feature reports, leaving
their Device Mode alone; one that cannot be opened for lack of permission gets the udev rule that
grants access (the `hidraw` backend needs read/write access to `/dev/hidraw*`, see
`gazehdr.drivers.hid.source`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from gazehdr.drivers.hid.descriptor import DescriptorError
from gazehdr.drivers.hid.source import HidTracker, default_backend
from gazehdr.drivers.hid.tracker import TrackerInfo, path_str
from gazehdr.drivers.hid.usages import USAGE_PAGE


@dataclass(frozen=True)
class DeviceReport:
    """One HID interface found by enumeration, and whether gazehdr can use it."""

    path: str
    vendor_id: int
    product_id: int
    product: str
    usage_page: int
    usage: int
    usable: bool
    reason: str
    udev_rule: str | None = None
    info: TrackerInfo | None = None


def udev_rule(vendor_id: int, product_id: int) -> str:
    return (
        f'SUBSYSTEM=="hidraw", ATTRS{{idVendor}}=="{vendor_id:04x}", '
        f'ATTRS{{idProduct}}=="{product_id:04x}", MODE="0660", GROUP="plugdev"'
    )


def list_devices(
    backend: Any = None, *, access: Callable[[str, int], bool] = os.access
) -> list[DeviceReport]:
    """Every HID interface hidapi enumerates, with why it is usable or skipped.

    Eye trackers (usage page 0x12) are opened to read their descriptor and feature reports (their
    Device Mode is left alone). One that cannot be opened because of permissions gets the udev
    rule that grants access.
    """
    backend = backend or default_backend()
    out: list[DeviceReport] = []
    for e in backend.enumerate():
        path = path_str(e["path"])
        vid, pid = int(e.get("vendor_id") or 0), int(e.get("product_id") or 0)
        page, use = int(e.get("usage_page") or 0), int(e.get("usage") or 0)
        base = {
            "path": path,
            "vendor_id": vid,
            "product_id": pid,
            "product": e.get("product_string") or "",
            "usage_page": page,
            "usage": use,
        }
        if page != USAGE_PAGE:
            why = f"usage page 0x{page:04x} is not Eye and Head Trackers (0x0012)"
            out.append(DeviceReport(**base, usable=False, reason=why))
            continue
        dev = backend.device()
        try:
            dev.open_path(e["path"])
        except OSError as err:
            if os.path.exists(path) and not access(path, os.R_OK | os.W_OK):
                why = f"permission denied on {path}"
                out.append(
                    DeviceReport(**base, usable=False, reason=why, udev_rule=udev_rule(vid, pid))
                )
            else:
                out.append(DeviceReport(**base, usable=False, reason=f"cannot open: {err}"))
            continue
        try:
            tracker = HidTracker(dev, e, set_mode=False)
        except (DescriptorError, OSError, ValueError) as err:
            out.append(DeviceReport(**base, usable=False, reason=str(err)))
            continue
        finally:
            dev.close()
        info = tracker.info
        parts = ["eye tracker"]
        if info.calibrated_screen_um:
            w, h = info.calibrated_screen_um
            parts.append(f"calibrated screen {w / 1000:.1f} × {h / 1000:.1f} mm")
        else:
            parts.append("no calibrated screen size (the screen geometry is used)")
        if info.sampling_hz:
            parts.append(f"{info.sampling_hz:g} Hz")
        out.append(DeviceReport(**base, usable=True, reason=", ".join(parts), info=info))
    return out


def devices_main(argv: Sequence[str] | None = None, *, backend: Any = None) -> int:
    """`gazehdr devices`: list HID interfaces; 0 when the listing worked, whatever it found (1
    with `--require` when no eye tracker is usable; 2 when devices cannot be listed)."""
    parser = argparse.ArgumentParser(
        prog="gazehdr devices",
        description="List HID devices and whether each is a usable eye tracker (usage page "
        "0x12); for one that cannot be opened, print the udev rule that grants access.",
    )
    parser.add_argument(
        "--trackers-only", action="store_true", help="list only usage page 0x12 devices"
    )
    parser.add_argument(
        "--require",
        action="store_true",
        help="exit with 1 when no eye tracker is usable (for scripts; default: 0 once listed)",
    )
    args = parser.parse_args(list(argv) if argv is not None else None)
    try:
        found = list_devices(backend)
    except ModuleNotFoundError as e:
        print(f"gazehdr devices: {e}", file=sys.stderr)
        return 2
    shown = [d for d in found if d.usage_page == USAGE_PAGE or not args.trackers_only]
    if not shown:
        print("no HID devices found" if not found else "no HID eye trackers found")
    rules: list[str] = []
    for d in shown:
        mark = "ok  " if d.usable else "skip"
        name = f" {d.product}" if d.product else ""
        print(f"{mark} {d.path} {d.vendor_id:04x}:{d.product_id:04x}{name}: {d.reason}")
        if d.udev_rule and d.udev_rule not in rules:
            rules.append(d.udev_rule)
    if rules:
        print(
            "\nTo use the tracker without root, add to /etc/udev/rules.d/70-gazehdr.rules:\n"
            + "\n".join(f"  {r}" for r in rules)
            + "\nthen run 'sudo udevadm control --reload-rules && sudo udevadm trigger', be in "
            "the plugdev group, and re-plug the tracker."
        )
    return 1 if args.require and not any(d.usable for d in found) else 0
