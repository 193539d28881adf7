"""The real-kernel HID harness: a QEMU guest with Debian's kernel, virtual trackers through
uhid, read by the unchanged gazehdr commands through hidapi's hidraw backend.

`run.py` makes and boots the guest (host side), `agent.py` is the harness's process in the
guest, `uhid.py` the uhid device side, `descriptors.py` the trackers and the devices that lie.
The tests are tests/test_hid_kernel.py (`pytest -m hid_kernel`); docs/gaze.md, "Tested against a
real kernel", says what they cover.
"""
