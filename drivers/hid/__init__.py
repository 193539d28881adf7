"""Gaze from eye trackers that implement USB HID usage page 0x12, Eye and Head Trackers.

The decoding is pure and tested with bytes alone; the device I/O is a thin shell over it:

- `usages`: the usage page's usages, Device Mode bits and canonical units;
- `descriptor`: report descriptors (parsed by hid-tools, GPL-2.0, imported only there; why
  hid-tools and which of its quirks are worked around is in its docstring) and the decoding and
  encoding of the reports they describe;
- `tracker`: what a tracker's reports say: its gaze report, feature reports as `TrackerInfo`,
  the Device Mode to request, a decoded report as a `GazeSample` in screen pixels;
- `clock`: Sensor Timestamps (µs on the tracker's clock) as host monotonic ns;
- `source`: hidapi (which backend, and why), opening a tracker, reading it, reconnecting with
  back-off: `HidGazeSource`, the `hid[:PATH]` source of `gazehdr.drivers.registry`;
- `devices`: the `gazehdr devices` command.

Nothing is imported here, so that `gazehdr.drivers.hid.descriptor` comes without the I/O; the
modules log as children of the `gazehdr.drivers.hid` logger, which `gazehdr daemon` prints.
"""
