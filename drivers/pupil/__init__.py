"""Gaze from Pupil Capture (Pupil Labs' Pupil Core software) through its Network API.

The decoding is pure and tested with bytes alone; the ZeroMQ I/O is a thin shell over it:

- `protocol`: the `pupil:HOST[:PORT][/SURFACE]` spec, Pupil Remote's replies, the backbone's
  `surfaces.NAME` messages and their gaze datums as `GazeSample`s on the screen (msgpack);
- `clock`: Pupil time on the host clock, from `t` round trips, the arithmetic alone;
- `source`: Pupil Remote's REQ socket, the SUB socket, clock syncs, reconnecting with back-off:
  `PupilGazeSource`, the `pupil` source of `gazehdr.drivers.registry` (pyzmq).

Nothing is imported here, so that `protocol` and `clock` come without pyzmq; the modules log as
children of the `gazehdr.drivers.pupil` logger, which `gazehdr daemon` prints.
"""
