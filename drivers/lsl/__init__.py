"""Lab Streaming Layer, both ways: gaze in from a tracker's LSL app, gaze and events out to
LabRecorder.

- `meta`: what a stream's description says (pure): the query a spec names, the channel layout
  read from the XML description (the XDF gaze meta-data conventions, and the layouts real
  trackers' apps publish), a sample's values as a `GazeSample`, and the description and values
  gazehdr publishes. `gazehdr.drivers.formats.xdf` reads recorded streams with it too.
- `clock`: LSL time ↔ the host's monotonic nanoseconds, and a stream's clock correction (pure).
- `source`: the `lsl[:QUERY]` gaze source (pylsl inlet, reconnecting with back-off).
- `outlet`: the gaze and marker outlets the daemon and `gazehdr serve` publish.

Only `source` and `outlet` import pylsl (the `gazehdr[lsl]` extra).
"""

from __future__ import annotations

from types import ModuleType


def load_pylsl() -> ModuleType:
    """pylsl, with liblsl loaded; ModuleNotFoundError naming the extra where either is missing
    (the registry reports it as "LSL source unavailable: ...")."""
    try:
        import pylsl
    except ModuleNotFoundError as e:
        raise ModuleNotFoundError(
            "Lab Streaming Layer needs pylsl: install gazehdr[lsl]", name=e.name
        ) from None
    except RuntimeError as e:  # pylsl without a liblsl it can load
        raise ModuleNotFoundError(f"pylsl cannot load liblsl ({e}): install gazehdr[lsl]") from None
    return pylsl
