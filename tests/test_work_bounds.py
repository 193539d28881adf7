"""Every parameter that sizes the work of a step is bounded before anything is built: a blur's
radius, a grid's cells, a band count, key frames a second, the viewing geometry. A value past
its bound is refused with the bound named, in Python, over REST and from a viewer, and the
server goes on unchanged. Each test names the mutation it guards.
"""

from __future__ import annotations

import json
import re

import pytest

from gazehdr.sim import Geometry, Params
from gazehdr.sim.layout import MAX_BLUR_SIGMA, MAX_SIZE, Layout
from gazehdr.sim.params import MAX_PPD, WORK_BOUNDS
from tests.test_server import Client, http, run


@pytest.mark.parametrize("name", sorted(WORK_BOUNDS))
def test_each_bounded_value_is_refused_past_its_bound_and_taken_at_it(name: str) -> None:
    """The bound itself is allowed, just past it is refused with the bound in the message.
    Guards a bound dropped from WORK_BOUNDS' check (sigma_0 = 1e9 built a blur of 3e9 px)."""
    low, high, _ = WORK_BOUNDS[name]
    integer = isinstance(getattr(Params(), name), int)
    Params(**{name: int(high) if integer else high})
    past = int(high) + 1 if integer else high * 1.01
    with pytest.raises(ValueError, match=rf"{name} = .* is outside \[{low:g}, {high:g}\]"):
        Params(**{name: past})
    if low > 0:
        with pytest.raises(ValueError, match=rf"{name} = .* is outside"):
            Params(**{name: int(low) - 1 if integer else low / 2})


def test_the_geometry_is_bounded_by_its_pixels_per_degree() -> None:
    """A tiny screen seen from far away turns every size in degrees into thousands of pixels.
    Guards the geometry's check (a 4 mm, 16 px screen at 100 m gives 1e4 px per degree)."""
    with pytest.raises(ValueError, match="px per degree, outside"):
        Geometry(screen_width_px=16, screen_height_px=16, screen_diagonal_m=0.004,
                 viewing_distance_m=100.0)  # fmt: skip
    with pytest.raises(ValueError, match=r"screen_width_px must be an integer in \[16, 16384\]"):
        Geometry(screen_width_px=10**9)
    with pytest.raises(ValueError, match="px per degree"):
        Params.from_dict({"geometry": {"viewing_distance_m": 100.0, "screen_diagonal_m": 0.05}})
    assert Geometry().pixels_per_degree() < MAX_PPD


def test_a_large_frame_of_a_small_screen_is_refused_by_its_widest_blur() -> None:
    """Values inside their bounds can still combine into a blur too wide: a 320 px geometry
    shown on a 7680 px frame multiplies the acuity bank's sigma by 24. Guards the layout's
    combined check (check_work skipped: a 646 px blur, radius 1900 taps)."""
    small = Geometry(screen_width_px=320, screen_height_px=180)
    Layout.for_frame(*MAX_SIZE, Params())  # the defaults at the largest frame
    with pytest.raises(
        ValueError, match=rf"sigma_0 gives a blur of sigma .* over the {MAX_BLUR_SIGMA:g}"
    ):
        Layout.for_frame(*MAX_SIZE, Params(sigma_0=8.0, geometry=small))


def test_rest_refuses_values_past_their_bounds_and_keeps_the_defaults(live_server) -> None:
    """PUT /api/params with sigma_0 1e9, bands 17 or a blur too wide for the server's frames:
    a 422 naming the bound, and new sessions start as before. Guards the route's check of the
    work (bands 17 was accepted, and every new viewer was then refused)."""
    server = live_server()
    _, before = http("GET", server.url + "/api/params")
    json_body = {"content-type": "application/json"}
    for change, bound in (
        ({"sigma_0": 1e9}, r"sigma_0 = 1e\+09 is outside \[0, 8\]"),
        ({"bands": 17}, r"bands = 17 is outside \[1, 8\]"),
        ({"sigma_0": 8.0, "geometry": {"screen_width_px": 16, "screen_height_px": 16,
                                       "screen_diagonal_m": 0.3}},
         "sigma_0 gives a blur of sigma .* over the 128"),
    ):  # fmt: skip
        status, err = http("PUT", server.url + "/api/params", json.dumps(change).encode(),
                           **json_body, **server.auth)  # fmt: skip
        assert status == 422 and re.search(bound, err["detail"]), (change, err)
    _, after = http("GET", server.url + "/api/params")
    assert after["params"] == before["params"]

    async def viewer_refused_then_served() -> None:
        client = await Client.open(server)
        await client.send(type="params", values={"sigma_0": 1e5})
        error = await client.note("error")
        assert error["in"] == "params" and "sigma_0 = 100000 is outside [0, 8]" in error["message"]
        await client.send(type="params", values={"bands": 17})
        assert "bands = 17 is outside" in (await client.note("error"))["message"]
        await client.frame()  # the session goes on
        await client.ws.close()
        fresh = await Client.open(server)  # and a new viewer is served
        assert fresh.hello["params"]["sigma_0"] == Params().sigma_0
        await fresh.frame()
        await fresh.ws.close()

    run(viewer_refused_then_served())
