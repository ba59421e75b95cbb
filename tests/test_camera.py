"""Tests of warp_hair.renderer.camera: where rays go, checked against brute-force projection of world points."""

import math

import numpy as np
import pytest

from warp_hair.renderer.camera import camera_rays
from warp_hair.scene import Camera

RESOLUTION = (48, 32)  # not square, to tell the horizontal extent from the vertical one


def _camera(kind, origin=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)):
    lens = {"width": 1.5} if kind == "orthographic" else {"fov": 40.0}
    return Camera(type=kind, origin=origin, target=target, up=up, resolution=RESOLUTION, **lens)


CAMERAS = [
    _camera("orthographic"),
    _camera("perspective"),
    # Oblique views with up not perpendicular to the view direction.
    _camera("orthographic", origin=(1.0, 2.0, 3.0), target=(-0.5, 0.2, 0.1), up=(0.3, 0.1, 1.0)),
    _camera("perspective", origin=(1.0, 2.0, 3.0), target=(-0.5, 0.2, 0.1), up=(0.3, 0.1, 1.0)),
]
IDS = ["ortho", "persp", "ortho-oblique", "persp-oblique"]


def _pixel_grid():
    width, height = RESOLUTION
    return np.meshgrid(np.arange(width), np.arange(height))  # (H, W) each: px, py


def _nearest_pixel(camera, point):
    """(px, py) of the pixel-centre ray passing closest to `point`, by trying every pixel."""
    origins, directions = camera_rays(camera, *_pixel_grid())
    to_point = point - origins.astype(np.float64)
    along = np.sum(to_point * directions, axis=-1, keepdims=True)
    miss = np.linalg.norm(to_point - along * directions, axis=-1)
    py, px = np.unravel_index(np.argmin(miss), miss.shape)
    return px, py


def _frame(camera):
    forward = np.subtract(camera.target, camera.origin)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    return forward, right, np.cross(right, forward)


@pytest.mark.parametrize("camera", CAMERAS, ids=IDS)
def test_centre_ray_goes_along_forward(camera):
    width, height = RESOLUTION
    # The corner shared by the four central pixels is the centre of the image.
    origins, directions = camera_rays(camera, width // 2, height // 2, jitter=(0.0, 0.0))
    forward = _frame(camera)[0]
    np.testing.assert_allclose(directions, forward, atol=1e-6)
    np.testing.assert_allclose(origins, camera.origin, atol=1e-6)


@pytest.mark.parametrize("camera", CAMERAS, ids=IDS)
def test_directions_are_unit(camera):
    _, directions = camera_rays(camera, *_pixel_grid(), jitter=np.random.default_rng(1).random((*RESOLUTION[::-1], 2)))
    np.testing.assert_allclose(np.linalg.norm(directions, axis=-1), 1.0, atol=1e-6)


@pytest.mark.parametrize("camera", CAMERAS, ids=IDS)
def test_up_is_the_top_and_forward_cross_up_the_right(camera):
    width, height = RESOLUTION
    forward, right, up = _frame(camera)
    centre = np.array(camera.origin) + 3.0 * forward
    shift = 0.3
    px, py = _nearest_pixel(camera, centre + shift * up)
    assert py < height // 2 - 2 and abs(px - width / 2) <= 1
    px, py = _nearest_pixel(camera, centre - shift * up)
    assert py > height // 2 + 2 and abs(px - width / 2) <= 1
    px, py = _nearest_pixel(camera, centre + shift * right)
    assert px > width // 2 + 2 and abs(py - height / 2) <= 1


@pytest.mark.parametrize("camera", CAMERAS, ids=IDS)
def test_brute_force_projection_matches_the_lens(camera):
    """World points land on the pixel the camera's extents predict."""
    width, height = RESOLUTION
    forward, right, up = _frame(camera)
    rng = np.random.default_rng(3)
    for _ in range(5):
        depth = rng.uniform(2.0, 4.0)
        x, y = rng.uniform(-0.4, 0.4, 2)  # fractions of the view's half extents
        if camera.type == "orthographic":
            half_width = 0.5 * camera.width
        else:
            half_width = depth * math.tan(math.radians(camera.fov / 2))
        half_height = half_width * height / width
        point = np.array(camera.origin) + depth * forward + 2 * x * half_width * right + 2 * y * half_height * up
        expected = (math.floor((0.5 + x) * width), math.floor((0.5 - y) * height))
        assert _nearest_pixel(camera, point) == expected


def _edge_rays(camera):
    """Rays through the middle of the left, right, top and bottom edges of the image."""
    width, height = RESOLUTION
    px = np.array([0, width - 1, width // 2, width // 2])
    py = np.array([height // 2, height // 2, 0, height - 1])
    jitter = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    return camera_rays(camera, px, py, jitter)


def test_orthographic_extents():
    camera = CAMERAS[2]
    width, height = RESOLUTION
    forward, right, up = _frame(camera)
    origins, directions = _edge_rays(camera)
    np.testing.assert_allclose(directions, np.broadcast_to(forward, (4, 3)), atol=1e-6)
    left, right_edge, top, bottom = origins
    np.testing.assert_allclose(right_edge - left, camera.width * right, atol=1e-5)
    np.testing.assert_allclose(top - bottom, camera.width * height / width * up, atol=1e-5)


def test_perspective_fields_of_view():
    camera = CAMERAS[3]
    width, height = RESOLUTION
    origins, directions = _edge_rays(camera)
    np.testing.assert_allclose(origins, np.broadcast_to(camera.origin, (4, 3)), atol=1e-6)
    left, right, top, bottom = directions.astype(np.float64)
    horizontal = math.degrees(math.acos(np.dot(left, right)))
    vertical = math.degrees(math.acos(np.dot(top, bottom)))
    assert horizontal == pytest.approx(camera.fov, abs=1e-3)
    expected_vertical = 2 * math.degrees(math.atan(math.tan(math.radians(camera.fov / 2)) * height / width))
    assert vertical == pytest.approx(expected_vertical, abs=1e-3)


def test_jitter_spans_the_pixel():
    camera = CAMERAS[0]
    # The far corner of pixel (3, 4) is the near corner of pixel (4, 5).
    far, _ = camera_rays(camera, 3, 4, jitter=(1.0, 1.0))
    near, _ = camera_rays(camera, 4, 5, jitter=(0.0, 0.0))
    np.testing.assert_allclose(far, near, atol=1e-6)
