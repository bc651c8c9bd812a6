"""The scene renderer: exact cases, the analytic orbiting disk, buffers against the rendered motion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diffblur import scenes, shutters
from diffblur.scenes import (
    PRESETS,
    Affine,
    Camera,
    CurvedPath,
    ImageTexture,
    InverseDepthPlane,
    Layer,
    Rotation,
    Scene,
    Static,
    Translation,
    accumulate,
    make_scene,
    orbiting_disk_density,
    orbiting_disk_scene,
    render,
    required_instants,
    trace,
)

SIZE = 48  # small presets keep the suite fast; motions scale with the size (~5 px here)


@pytest.fixture(scope="module")
def presets():
    return {name: make_scene(name, height=SIZE, width=SIZE + 8, seed=3) for name in PRESETS}


# --- exact cases ----------------------------------------------------------------------------------


def test_static_scene_target_equals_color_exactly():
    scene = make_scene("static", height=40, width=52)
    assert scene.instants == 1
    np.testing.assert_array_equal(scene.target, scene.color)
    np.testing.assert_array_equal(scene.velocity, 0.0)
    np.testing.assert_array_equal(scene.offset_prev, 0.0)
    np.testing.assert_array_equal(scene.offset_next, 0.0)
    # Many instants of a still scene still average to the same picture (weights sum to 1).
    many = make_scene("static", height=40, width=52, shutter="gaussian", instants=9)
    np.testing.assert_allclose(many.target, many.color, rtol=0, atol=1e-14)


def _random_texture(rng, height, width, origin):
    return ImageTexture(rng.random((height, width, 3)), None, origin)


def test_translating_scene_target_is_the_average_of_shifted_frames():
    rng = np.random.default_rng(7)
    height, width = 30, 40
    background = rng.random((height, width, 3))
    fg_color = rng.random((10, 12, 3))
    fg_alpha = np.clip(rng.random((10, 12)) * 1.5, 0, 1)
    fg_alpha[0] = fg_alpha[-1] = fg_alpha[:, 0] = fg_alpha[:, -1] = 0.0  # transparent border
    top, left = 10, 14
    velocity = (5.0, -2.5)
    layers = (
        Layer(ImageTexture(background, None, (0, 0)), 10.0, Static(), "bg"),
        Layer(ImageTexture(fg_color, fg_alpha, (left, top)), 2.0, Translation(velocity), "fg"),
    )
    scene = Scene(height, width, layers)
    for shutter in ("box", "tent", shutters.LinearRamp(0.6)):
        target, count = accumulate(scene, shutter=shutter, instants=5)
        times, weights = shutters.instants(shutter, 5)
        expected = np.zeros((height, width, 3))
        for t, w in zip(times, weights):
            # 5 strata: t = -0.8 ... 0.8, so the shifts v t are whole pixels.
            dx, dy = int(round(velocity[0] * t)), int(round(velocity[1] * t))
            color = np.zeros((height, width, 3))
            alpha = np.zeros((height, width))
            color[top + dy : top + dy + 10, left + dx : left + dx + 12] = fg_color
            alpha[top + dy : top + dy + 10, left + dx : left + dx + 12] = fg_alpha
            frame = alpha[..., None] * color + (1 - alpha[..., None]) * background
            expected += w * frame
        assert count == 5
        np.testing.assert_allclose(target[0].transpose(1, 2, 0), expected, rtol=0, atol=1e-12)


def test_occlusion_nearest_depth_wins_whatever_the_layer_order():
    red = ImageTexture(np.tile([1.0, 0.0, 0.0], (12, 12, 1)), np.pad(np.ones((8, 8)), 2), (2, 2))
    blue = ImageTexture(np.tile([0.0, 0.0, 1.0], (12, 12, 1)), np.pad(np.ones((8, 8)), 2), (6, 6))
    near_red = [Layer(red, 2.0, name="red"), Layer(blue, 3.0, name="blue")]
    for layers in (near_red, near_red[::-1]):
        frame = render(Scene(20, 20, tuple(layers)))
        # Overlap of the two squares: pixels 8..11 in x and y.
        np.testing.assert_array_equal(frame.color[0, :, 9, 9], [1.0, 0.0, 0.0])
        np.testing.assert_array_equal(frame.color[0, :, 13, 13], [0.0, 0.0, 1.0])
        assert frame.depth[0, 0, 9, 9] == 2.0 and frame.depth[0, 0, 13, 13] == 3.0
        assert frame.depth[0, 0, 0, 0] == scenes.FAR_DEPTH and frame.layer[0, 0, 0, 0] == -1


def test_occlusion_per_pixel_with_a_tilted_plane():
    # A wall at depth 5 and a floor whose depth runs from 9 (row 0) to 1 (row 19): the floor is in
    # front below the row where it passes depth 5, behind above it.
    wall = ImageTexture(np.tile([1.0, 1.0, 0.0], (20, 20, 1)), None, (0, 0))
    floor = ImageTexture(np.tile([0.0, 1.0, 1.0], (20, 20, 1)), None, (0, 0))
    plane = InverseDepthPlane.through_rows(0.0, 9.0, 19.0, 1.0)
    scene = Scene(20, 20, (Layer(wall, 5.0), Layer(floor, plane)))
    frame = render(scene)
    depth_of_rows = 1.0 / plane.inverse_depth(0.0, np.arange(20.0))
    floor_in_front = depth_of_rows < 5.0
    assert 0 < floor_in_front.sum() < 20
    expected = np.where(floor_in_front[:, None], [0.0, 1.0, 1.0], [1.0, 1.0, 0.0])
    np.testing.assert_array_equal(frame.color[0].transpose(1, 2, 0), np.broadcast_to(expected[:, None, :], (20, 20, 3)))
    np.testing.assert_allclose(frame.depth[0, 0, :, 0], np.minimum(depth_of_rows, 5.0), rtol=1e-14)


# --- seed 004: the orbiting disk ------------------------------------------------------------------

DISK = dict(center=(30.0, 33.0), orbit_radius=14.0, disk_radius=7.0, angle=1.2, phase=0.3)


def _brute_force_density(x, y, *, center, orbit_radius, disk_radius, angle, phase, shutter, samples=200001):
    """Direct quadrature of the coverage indicator over time at one point (no renderer, no formula)."""
    window = shutters.get_shutter(shutter)
    t = np.linspace(-1, 1, samples)
    cx = center[0] + orbit_radius * np.cos(phase + angle * t)
    cy = center[1] + orbit_radius * np.sin(phase + angle * t)
    inside = (x - cx) ** 2 + (y - cy) ** 2 < disk_radius**2
    values = window.weight(t) * inside
    return float(np.sum(0.5 * (values[1:] + values[:-1])) * (t[1] - t[0]))


@pytest.mark.parametrize(
    "geometry",
    [
        DISK,
        dict(center=(20.0, 20.0), orbit_radius=9.0, disk_radius=4.0, angle=9.0, phase=-2.0),  # > 1 turn
        dict(center=(20.0, 20.0), orbit_radius=3.0, disk_radius=6.0, angle=-0.8, phase=1.0),  # covers centre
    ],
    ids=["slow", "wrapping", "over-centre"],
)
@pytest.mark.parametrize("shutter", ["box", "raised_cosine", "linear_ramp"])
def test_orbiting_disk_formula_matches_brute_force(geometry, shutter):
    density = orbiting_disk_density(60, 64, shutter=shutter, **geometry)
    assert density.shape == (1, 1, 60, 64)
    rng = np.random.default_rng(11)
    cx, cy = geometry["center"]
    # Points along the orbit (where the density varies) and a few random ones.
    angles = rng.uniform(-np.pi, np.pi, 10)
    radius = geometry["orbit_radius"]
    points = [(int(round(cx + radius * np.cos(a))), int(round(cy + radius * np.sin(a)))) for a in angles]
    points += [tuple(p) for p in rng.integers([0, 0], [64, 60], size=(6, 2))]
    for x, y in points:
        expected = _brute_force_density(x, y, shutter=shutter, **geometry)
        assert density[0, 0, y, x] == pytest.approx(expected, abs=4e-5), (x, y)
    assert 0.0 <= density.min() and density.max() <= 1.0 + 1e-12


def test_orbiting_disk_static_cases():
    # No rotation, or a disk centred on its orbit: the density is the disk itself.
    # (A radius off the pixel lattice: no pixel centre lies on the edge.)
    still = orbiting_disk_density(30, 30, center=(15.0, 15.0), orbit_radius=6.0, disk_radius=4.3, angle=0.0)
    y, x = np.mgrid[0:30, 0:30]
    np.testing.assert_array_equal(still[0, 0], ((x - 21.0) ** 2 + (y - 15.0) ** 2 < 4.3**2).astype(float))
    centred = orbiting_disk_density(30, 30, center=(15.0, 15.0), orbit_radius=0.0, disk_radius=4.3, angle=2.0)
    np.testing.assert_array_equal(centred[0, 0], ((x - 15.0) ** 2 + (y - 15.0) ** 2 < 4.3**2).astype(float))


@pytest.mark.parametrize("shutter", ["box", "raised_cosine", "linear_ramp"])
def test_accumulation_converges_to_the_analytic_disk(shutter):
    exact = orbiting_disk_density(64, 64, shutter=shutter, **DISK)
    scene = orbiting_disk_scene(64, 64, **DISK)
    window = shutters.get_shutter(shutter)
    peak = float(window.weight(np.linspace(-1, 1, 2001)).max())
    max_errors, mean_errors = [], []
    counts = [16, 64, 256, 1024]
    for count in counts:
        target, _ = accumulate(scene, shutter=shutter, instants=count)
        error = np.abs(target - exact)  # every channel of the white disk is the density
        max_errors.append(error.max())
        mean_errors.append(error.mean())
        # Midpoint instants with exact stratum weights: a pixel is wrong only in the strata where the
        # disk's edge crosses it, once entering and once leaving, each by at most one stratum's weight.
        assert error.max() <= 2 * peak * (2.0 / count) + 1e-12
    # First-order convergence: 4x the instants, about 4x smaller errors.
    assert all(a / b > 3.0 for a, b in zip(mean_errors, mean_errors[1:]))
    assert mean_errors[-1] < 6e-5 and max_errors[-1] < 1.5e-3


# --- buffers against the rendered motion ----------------------------------------------------------


def _bilinear(field, x, y):
    """field (C, H, W) at points (x, y) (N,), clamped."""
    h, w = field.shape[1:]
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    j = np.minimum(np.floor(x).astype(int), w - 2)
    i = np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = x - j, y - i
    top = field[:, i, j] * (1 - fx) + field[:, i, j + 1] * fx
    bottom = field[:, i + 1, j] * (1 - fx) + field[:, i + 1, j + 1] * fx
    return top * (1 - fy) + bottom * fy


def _same_layer_around(layer_map, x, y, index):
    """True where the 4 pixels around (x, y) all show layer `index`."""
    h, w = layer_map.shape
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    j = np.clip(np.floor(x).astype(int), 0, w - 2)
    i = np.clip(np.floor(y).astype(int), 0, h - 2)
    same = inside.copy()
    for di in (0, 1):
        for dj in (0, 1):
            same &= layer_map[i + di, j + dj] == index
    return same


@pytest.mark.parametrize("name", PRESETS)
@pytest.mark.parametrize("end", [-1.0, 1.0], ids=["prev", "next"])
def test_offsets_land_where_the_renderer_shows_the_point(presets, name, end):
    """Render the instant t = +-1 and read, at X + offset, which layer point the renderer shows there:
    it must be the point seen at X at t = 0 (its layer coordinates are X)."""
    buffers = presets[name]
    scene = buffers.scene
    offset = buffers.offset_next if end > 0 else buffers.offset_prev
    now = render(scene, 0.0)
    later = render(scene, end)
    h, w = scene.height, scene.width
    y, x = np.mgrid[0:h, 0:w].astype(float)
    px, py = (x + offset[0, 0]).ravel(), (y + offset[0, 1]).ravel()
    checked = 0
    for index in np.unique(now.layer):
        if index < 0:
            continue
        mine = (now.layer[0, 0].ravel() == index) & _same_layer_around(later.layer[0, 0], px, py, index)
        if not np.any(mine):
            continue
        landed = _bilinear(later.source[0], px[mine], py[mine])
        np.testing.assert_allclose(landed[0], x.ravel()[mine], atol=2e-3)
        np.testing.assert_allclose(landed[1], y.ravel()[mine], atol=2e-3)
        checked += mine.sum()
    assert checked > 0.3 * h * w


def _velocity_over_derivative(scene, layer_map):
    """Per pixel, |V| / |dp/dt(0)| implied by each preset's motion law (1 for motion linear in t)."""
    ratio = np.ones(layer_map.shape)
    for index, layer in enumerate(scene.layers):
        mask = layer_map == index
        if isinstance(layer.motion, Rotation):
            # V = (p(1) - p(-1)) / 2 is the chord: sin(angle) / angle of the tangent speed.
            ratio[mask] = math.sin(layer.motion.angle) / layer.motion.angle
        if scene.camera.advance:
            # p(t) - c = (X - c) d / (d - a t): V = (X - c) a d / (d^2 - a^2), dp/dt(0) = (X - c) a / d.
            d, a = 1.0 / layer.depth.i0, scene.camera.advance
            ratio[mask] = d * d / (d * d - a * a)
    return ratio


@pytest.mark.parametrize("name", [n for n in PRESETS if n != "static"])
def test_velocity_agrees_with_finite_differences_of_the_rendered_motion(presets, name):
    """dp/dt at t = 0 from the renderer: the layer coordinates shown at X at t = -h and t = +h."""
    buffers = presets[name]
    scene = buffers.scene
    h_step = 1e-4
    before, now, after = render(scene, -h_step), render(scene, 0.0), render(scene, h_step)
    same = (before.layer == now.layer) & (after.layer == now.layer) & (now.layer >= 0)
    # Inverse map: the point at X at time +h came from X - h v, so dp/dt = (src(-h) - src(+h)) / 2h.
    derivative = (before.source - after.source) / (2 * h_step)
    expected = derivative * _velocity_over_derivative(scene, now.layer[0, 0])[None, None]
    mask = np.broadcast_to(same, buffers.velocity.shape)
    assert mask.mean() > 0.8
    np.testing.assert_allclose(buffers.velocity[mask], expected[mask], atol=1e-5, rtol=1e-6)
    # And the presets move: a few to ~15 px at 128 px, scaled to this size.
    speed = np.hypot(buffers.velocity[0, 0], buffers.velocity[0, 1])
    assert speed.max() > 1.0
    assert speed.max() < 16.0 * SIZE / 128 + 1e-9


def test_curved_and_affine_offsets_differ_from_linear(presets):
    # The crossing preset's disk bends (offsets are not +-V) while the translate preset's are.
    crossing, translate = presets["crossing"], presets["translate"]
    np.testing.assert_allclose(translate.offset_next, translate.velocity, atol=1e-12)
    np.testing.assert_allclose(translate.offset_prev, -translate.velocity, atol=1e-12)
    bend = crossing.offset_next + crossing.offset_prev  # = acceleration for the parabola
    disk = crossing.scene.layers[1]
    assert isinstance(disk.motion, CurvedPath)
    on_disk = render(crossing.scene).layer[0, 0] == 1
    acceleration = np.array(disk.motion.acceleration)[:, None]
    np.testing.assert_allclose(bend[0][:, on_disk], np.broadcast_to(acceleration, (2, on_disk.sum())), atol=1e-12)


def test_default_instants_keep_steps_below_a_quarter_pixel(presets):
    for name in ("translate", "gears", "zoom"):
        scene = presets[name].scene
        count = presets[name].instants
        assert count == required_instants(scene)
        for n, below in ((count, True), (count // 2, False)):
            times, _ = shutters.instants("box", n)
            path = trace(scene, times)  # (n, 2, H, W): the visible points over the exposure
            step = np.hypot(*np.diff(path, axis=0).transpose(1, 0, 2, 3)).max()
            assert (step < 0.25) == below, (name, n, step)


def test_buffers_shapes_and_conventions(presets):
    for name, buffers in presets.items():
        h, w = SIZE, SIZE + 8
        assert buffers.name == name
        fields = (("color", 3), ("target", 3), ("depth", 1), ("velocity", 2), ("offset_prev", 2), ("offset_next", 2))
        for field, channels in fields:
            array = getattr(buffers, field)
            assert array.shape == (1, channels, h, w), (name, field)
            assert array.dtype == np.float64 and np.all(np.isfinite(array))
        assert np.all(buffers.depth > 0)
        assert buffers.color.min() >= 0 and buffers.color.max() <= 1 + 1e-12
        np.testing.assert_allclose(buffers.velocity, 0.5 * (buffers.offset_next - buffers.offset_prev), atol=1e-12)
    # Static backgrounds come alone; camera motion moves the background, so there is none.
    assert presets["translate"].background.shape == (1, 3, SIZE, SIZE + 8)
    assert presets["pan"].background is None and presets["zoom"].background is None
    # Where nothing else covers it, the frame is the background.
    translate = presets["translate"]
    others = Scene(SIZE, SIZE + 8, translate.scene.layers[1:])
    seen = render(others).alpha[0, 0] == 0
    assert 0.3 < seen.mean() < 1
    np.testing.assert_array_equal(translate.color[0][:, seen], translate.background[0][:, seen])


def test_seed_is_deterministic_and_matters():
    a = make_scene("crossing", height=32, width=32, seed=5, instants=4)
    b = make_scene("crossing", height=32, width=32, seed=5, instants=4)
    c = make_scene("crossing", height=32, width=32, seed=6, instants=4)
    np.testing.assert_array_equal(a.target, b.target)
    assert not np.array_equal(a.velocity, c.velocity)


def test_motion_matrices_are_identity_at_zero():
    motions = [
        Translation((3.0, -1.0)),
        CurvedPath((2.0, 1.0), (0.5, -4.0)),
        Rotation((10.0, 7.0), 0.4),
        Affine(((0.1, -0.2), (0.2, 0.05)), (1.0, 2.0), (5.0, 5.0)),
    ]
    for motion in motions:
        np.testing.assert_array_equal(motion.matrices(0.0)[0], np.eye(3))
    camera = Camera(pan=(4.0, 1.0), advance=0.5, center=(8.0, 8.0))
    composed = camera.compose(motions[2].matrices(0.0), InverseDepthPlane(0.2, 0.01, -0.02), np.zeros(1))
    np.testing.assert_array_equal(composed[0], np.eye(3))


def test_gallery_writes_a_png(tmp_path):
    path = scenes.save_preset_gallery(tmp_path, height=24, width=24)
    with open(path, "rb") as handle:
        assert handle.read(8) == b"\x89PNG\r\n\x1a\n"


# --- bad arguments --------------------------------------------------------------------------------


def test_bad_arguments():
    with pytest.raises(ValueError, match="name must be one of 'static', 'translate'.*got 'spin'"):
        make_scene("spin")
    with pytest.raises(ValueError, match="height must be an integer >= 1, got 0"):
        make_scene("static", height=0)
    with pytest.raises(TypeError, match="width must be an integer >= 1, got 12.5"):
        make_scene("static", width=12.5)
    with pytest.raises(ValueError, match="height and width must be >= 8 pixels, got height=4"):
        make_scene("static", height=4)
    with pytest.raises(ValueError, match="instants must be an integer >= 1, got 0"):
        make_scene("static", instants=0)
    with pytest.raises(ValueError, match="shutter must be one of"):
        make_scene("static", height=16, width=16, shutter="hann")
    with pytest.raises(TypeError, match="seed must be an integer"):
        make_scene("static", seed="a")
    with pytest.raises(TypeError, match=r"velocity must be a pair of numbers \(x, y\)"):
        Translation((1.0,))
    with pytest.raises(ValueError, match="rate must keep I \\+ t \\* rate invertible"):
        Affine(((1.0, 0.0), (0.0, 1.0)))
    with pytest.raises(TypeError, match="texture must be an ImageTexture or FunctionTexture"):
        Layer("checkers", 2.0)
    with pytest.raises(ValueError, match="depth must be > 0, got -1"):
        Layer(_random_texture(np.random.default_rng(0), 4, 4, (0, 0)), -1.0)
    texture = _random_texture(np.random.default_rng(0), 4, 4, (0, 0))
    with pytest.raises(ValueError, match="camera advance must stay below every layer's depth"):
        Scene(4, 4, (Layer(texture, 2.0),), Camera(advance=2.5))
    with pytest.raises(ValueError, match="disk_radius must be > 0, got 0"):
        orbiting_disk_density(8, 8, center=(4, 4), orbit_radius=2.0, disk_radius=0.0, angle=1.0)
    with pytest.raises(ValueError, match="t must be finite, got nan"):
        render(Scene(4, 4, (Layer(texture, 2.0),)), float("nan"))
