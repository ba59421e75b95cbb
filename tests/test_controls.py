"""warp_hair.controls: the one table of the artist controls, and every reader of θ agrees with it."""

import dataclasses
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers import bsdf_grad

from optimize.latents import SPECS, parse_control_names
from optimize.linearize import COLUMNS
from warp_hair import cli
from warp_hair.controls import (
    COLOUR_CONTROLS,
    COLOUR_INPUTS,
    CONTROL_NAMES,
    CONTROLS,
    SCALAR_CONTROLS,
    THETA_SIZE,
    controls_of,
    named_theta,
    theta_vector,
)
from warp_hair.model.params import HairParams
from warp_hair.renderer.gradients import named_gradients
from warp_hair.scene import load_scene
from warp_hair.torch import allowed_controls

EXAMPLE_SCENE = Path(__file__).resolve().parents[1] / "examples" / "swatch.toml"

# One material per colour input, every control away from its default.
MATERIALS = {
    "albedo": HairParams(albedo=[0.7, 0.5, 0.3], beta_m=0.25, beta_n=0.4, alpha=-3.0, eta=1.7, r_roughness_scale=2.0),
    "sigma_a": HairParams(sigma_a=[0.2, 0.5, 1.1], beta_m=0.35, beta_n=0.2, alpha=4.0, eta=1.45, r_roughness_scale=0.5),
    "melanin": HairParams(
        eumelanin=1.3, pheomelanin=0.4, beta_m=0.45, beta_n=0.6, alpha=1.0, eta=1.6, r_roughness_scale=3.0
    ),
}


@pytest.mark.parametrize("colour_input", COLOUR_INPUTS)
def test_columns_tile_theta_for_each_colour_input(colour_input):
    """A material's controls fill distinct columns of θ, all of them but melanin's unused third colour column."""
    taken = [k for name in controls_of(colour_input) for k in CONTROLS[name].columns]
    assert len(taken) == len(set(taken)), f"overlapping columns: {sorted(taken)}"
    unused = set(range(THETA_SIZE)) - set(taken)
    assert unused == ({2} if colour_input == "melanin" else set())
    assert all(0 <= k < THETA_SIZE for k in taken)
    assert THETA_SIZE == 3 + len(SCALAR_CONTROLS)  # the colour's three columns, then one per scalar
    for name in controls_of(colour_input):
        assert len(CONTROLS[name].columns) == CONTROLS[name].size


def test_every_control_is_a_colour_control_or_a_scalar():
    assert set(CONTROL_NAMES) == set(SCALAR_CONTROLS) | {n for names in COLOUR_CONTROLS.values() for n in names}
    assert all(CONTROLS[name].default is not None for name in SCALAR_CONTROLS)
    assert set(COLOUR_CONTROLS) == set(COLOUR_INPUTS)


def _params_with(name, value):
    """A HairParams with control `name` at `value` (all channels of an RGB control), the rest valid."""
    control = CONTROLS[name]
    if control.colour_input is None:
        return HairParams(albedo=0.5, **{name: value})
    return HairParams(**{name: [value] * 3 if control.size == 3 else value})


def _inside(end, towards):
    return float(np.nextafter(end, towards))


@pytest.mark.parametrize("name", CONTROL_NAMES)
def test_hair_params_takes_exactly_the_tables_range(name):
    control = CONTROLS[name]
    middle = 0.5 * (control.lo + control.hi)
    label = f"{name}[r]" if control.size == 3 else name
    for end, is_open, outward in ((control.lo, control.lo_open, -math.inf), (control.hi, control.hi_open, math.inf)):
        accepted = _inside(end, middle) if is_open else end
        if control.float32 and is_open:
            # The kernels read it as float32: just inside in float64 rounds onto the bound (η = 1: not finite).
            with pytest.raises(ValueError, match=rf"^{name} = {accepted} is outside .* in float32.* rounds to {end}"):
                _params_with(name, accepted)
            accepted = float(np.nextafter(np.float32(end), np.float32(middle)))
        rejected = end if is_open else _inside(end, outward)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a roughness at 0 warns of the floor
            params = _params_with(name, accepted)
        given = params.to_dict()[name]
        assert (given[0] if control.size == 3 else given) == accepted
        with pytest.raises(ValueError) as error:
            _params_with(name, rejected)
        assert str(error.value) == f"{label} = {rejected} is outside the allowed range {control.interval}"
    assert control.interval[0] == ("(" if control.lo_open else "[")
    assert control.interval[-1] == (")" if control.hi_open else "]")


def test_defaults_are_the_tables():
    params = HairParams(albedo=0.5)
    assert {name: getattr(params, name) for name in SCALAR_CONTROLS} == {
        name: CONTROLS[name].default for name in SCALAR_CONTROLS
    }
    melanin = HairParams(eumelanin=1.0)
    assert melanin.pheomelanin == CONTROLS["pheomelanin"].default


@pytest.mark.parametrize("colour_input", COLOUR_INPUTS)
def test_hair_params_and_the_command_line_are_the_tables(colour_input):
    """One attribute of HairParams and one flag of the command line per control, named as in the table: a
    material's every control given as flags arrives in HairParams unchanged."""
    params = MATERIALS[colour_input]
    assert [f.name for f in dataclasses.fields(HairParams)] == [*list(CONTROL_NAMES), "albedo_inversion"]
    for name in CONTROL_NAMES:
        given = getattr(params, name)
        assert (given is None) == (name not in controls_of(colour_input))
    argv = ["plot-bsdf", "-o", "lobes.png"]
    for name, value in params.to_dict().items():
        argv += [f"--{name.replace('_', '-')}", *(str(v) for v in np.atleast_1d(value))]
    assert cli.hair_params(cli.build_parser().parse_args(argv)) == params
    # The derived σ_a has its own name; the sigma_a attribute is the input as given.
    if colour_input == "sigma_a":
        np.testing.assert_array_equal(params.absorption, params.sigma_a)
    else:
        assert params.sigma_a is None and params.absorption.shape == (3,) and np.all(params.absorption > 0)


@pytest.mark.parametrize("colour_input", COLOUR_INPUTS)
def test_to_dict_names_the_controls_of_its_colour_input(colour_input):
    params = MATERIALS[colour_input]
    assert params.colour_input == colour_input
    assert tuple(params.to_dict()) == controls_of(colour_input)
    assert HairParams.from_dict(params.to_dict()) == params


@pytest.mark.parametrize("colour_input", COLOUR_INPUTS)
def test_named_gradients_follow_the_table(colour_input):
    g = np.arange(1.0, THETA_SIZE + 1.0)
    named = named_gradients(MATERIALS[colour_input], g)
    assert tuple(named) == controls_of(colour_input)
    for name, value in named.items():
        np.testing.assert_array_equal(np.atleast_1d(value), g[list(CONTROLS[name].columns)])
        assert np.shape(value) == ((3,) if CONTROLS[name].size == 3 else ())


@pytest.mark.parametrize("colour_input", COLOUR_INPUTS)
def test_torch_allows_the_tables_controls(colour_input):
    scene = load_scene(EXAMPLE_SCENE)
    scene = dataclasses.replace(scene, hair=MATERIALS[colour_input])
    assert allowed_controls(scene) == COLOUR_CONTROLS[colour_input] + SCALAR_CONTROLS


def test_linearize_columns_are_the_tables():
    assert set(COLUMNS) == set(CONTROL_NAMES)
    for name in CONTROL_NAMES:
        assert COLUMNS[name] == list(CONTROLS[name].columns)


@pytest.mark.parametrize("colour_input", COLOUR_INPUTS)
def test_latent_specs_agree_with_the_table(colour_input):
    assert parse_control_names(list(controls_of(colour_input)), colour_input) == controls_of(colour_input)
    for other in COLOUR_INPUTS:
        for name in COLOUR_CONTROLS[other]:
            if other != colour_input:
                with pytest.raises(ValueError, match="colour"):
                    parse_control_names([name], colour_input)
    for name in controls_of(colour_input):
        spec, control = SPECS[name], CONTROLS[name]
        assert spec.size == control.size
        # The fit's interval lies inside the allowed range (or extends it to infinity where the range's upper
        # end is a float32 guard), and its neutral start is a valid control.
        assert spec.lo >= control.lo
        assert spec.hi <= control.hi or spec.hi == math.inf
        spec.check_start([spec.neutral] * spec.size, "neutral")
        assert control.contains(spec.neutral)


@pytest.mark.parametrize("colour_input", COLOUR_INPUTS)
def test_theta_round_trip(colour_input):
    """θ → names → θ is the identity; names → θ → names too (from a HairParams' own controls)."""
    rng = np.random.default_rng(COLOUR_INPUTS.index(colour_input))
    theta = rng.uniform(0.1, 0.9, THETA_SIZE)
    if colour_input == "melanin":
        theta[2] = 0.0  # the unused column
    named = named_theta(colour_input, theta)
    assert theta_vector(colour_input, named) == list(theta)

    params = MATERIALS[colour_input]
    theta = theta_vector(colour_input, params.to_dict())
    back = named_theta(colour_input, np.array(theta))
    assert {k: np.atleast_1d(v).tolist() for k, v in back.items()} == {
        k: np.atleast_1d(v).tolist() for k, v in params.to_dict().items()
    }
    # The gradient oracle's kernels carry the same θ, in float32.
    np.testing.assert_array_equal(np.array(bsdf_grad.hair_controls(params).theta), np.float32(theta))


def test_theta_vector_refuses_a_wrong_set_of_controls():
    with pytest.raises(ValueError, match="takes exactly"):
        theta_vector("albedo", {"albedo": [0.5] * 3})
    with pytest.raises(ValueError, match="takes 3 value"):
        theta_vector("sigma_a", dict(MATERIALS["sigma_a"].to_dict(), sigma_a=[1.0, 2.0]))
    with pytest.raises(ValueError, match=f"{THETA_SIZE} components"):
        named_theta("albedo", np.zeros(THETA_SIZE - 1))
    with pytest.raises(ValueError, match="unknown colour input"):
        controls_of("rgb")


def test_the_product_does_not_import_the_test_oracle():
    """θ's layout comes from the table: the renderer, the torch front and the fit load without the test oracle
    (tests/helpers/bsdf_grad.py) or any other test code."""
    code = (
        "import sys, warp_hair, warp_hair.torch, warp_hair.renderer.gradients, optimize.fit, optimize.linearize; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('tests', 'helpers') or 'bsdf_grad' in m))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert out.stdout.strip() == "[]"
