"""The Eye and Head Trackers usage page (0x12, HID Usage Tables, from HUTRR74), as gazehdr uses it.

An Eye Tracker application collection holds a Tracking Data input report: Sensor Timestamp
(0x20, µs on the tracker's clock) and a Gaze Point physical collection (0x24) holding Position X /
Position Y (0x21 / 0x22, µm from the top-left corner of the calibrated screen); and feature
reports: Capabilities (0x11), Configuration (0x12: Calibrated Screen Width / Height 0x204 / 0x205,
µm), Status (0x13: Sampling Frequency 0x300, Configuration Status 0x301) and Control (0x14: Device
Mode Request 0x400, a bit mask, 1 = gaze point, 2 = eye position, 4 = head position).

Usages are 32-bit extended usages (page << 16 | id), as hid-tools reports them.
"""

from __future__ import annotations

#: The Eye and Head Trackers usage page.
USAGE_PAGE = 0x12


def usage(usage_id: int) -> int:
    """A usage of the Eye and Head Trackers page as a 32-bit extended usage (page << 16 | id)."""
    return USAGE_PAGE << 16 | usage_id


EYE_TRACKER = usage(0x01)
HEAD_TRACKER = usage(0x02)
TRACKING_DATA = usage(0x10)
CAPABILITIES = usage(0x11)
CONFIGURATION = usage(0x12)
STATUS = usage(0x13)
CONTROL = usage(0x14)
SENSOR_TIMESTAMP = usage(0x20)
POSITION_X = usage(0x21)
POSITION_Y = usage(0x22)
POSITION_Z = usage(0x23)
GAZE_POINT = usage(0x24)
LEFT_EYE_POSITION = usage(0x25)
RIGHT_EYE_POSITION = usage(0x26)
HEAD_POSITION = usage(0x27)
TRACKER_QUALITY = usage(0x100)
MINIMUM_TRACKING_DISTANCE = usage(0x101)
OPTIMUM_TRACKING_DISTANCE = usage(0x102)
MAXIMUM_TRACKING_DISTANCE = usage(0x103)
MAXIMUM_SCREEN_PLANE_WIDTH = usage(0x104)
MAXIMUM_SCREEN_PLANE_HEIGHT = usage(0x105)
CALIBRATED_SCREEN_WIDTH = usage(0x204)
CALIBRATED_SCREEN_HEIGHT = usage(0x205)
SAMPLING_FREQUENCY = usage(0x300)
CONFIGURATION_STATUS = usage(0x301)
DEVICE_MODE_REQUEST = usage(0x400)

#: Device Mode Request bits.
MODE_GAZE_POINT = 1
MODE_EYE_POSITION = 2
MODE_HEAD_POSITION = 4

#: Canonical unit of each usage (what the usage table says it reports); values are converted to
#: it from the descriptor's Unit and Unit Exponent. Usages not listed are dimensionless.
UM, US, HZ = "µm", "µs", "Hz"
CANONICAL_UNITS: dict[int, str] = {
    SENSOR_TIMESTAMP: US,
    POSITION_X: UM,
    POSITION_Y: UM,
    POSITION_Z: UM,
    MINIMUM_TRACKING_DISTANCE: UM,
    OPTIMUM_TRACKING_DISTANCE: UM,
    MAXIMUM_TRACKING_DISTANCE: UM,
    MAXIMUM_SCREEN_PLANE_WIDTH: UM,
    MAXIMUM_SCREEN_PLANE_HEIGHT: UM,
    CALIBRATED_SCREEN_WIDTH: UM,
    CALIBRATED_SCREEN_HEIGHT: UM,
    SAMPLING_FREQUENCY: HZ,
}
