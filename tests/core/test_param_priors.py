"""compose --defect-priors: per-type parameter distributions drawn instead of a type's own ranges
(the built-in road_defects_br priors are measured from its train labels, bench/defect_priors.py)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy import stats
from shapely.geometry import Polygon

from cli_run import one_line, run_cli
from roadtwin_core import RoadtwinError, get_plugin_manager
from roadtwin_core.apps.compose.run import build_library
from roadtwin_core.model import ComposeRules
from roadtwin_core.town.param_priors import FieldPrior, apply_priors, load_priors


def write(tmp_path, text: str):
    p = tmp_path / "priors.toml"
    p.write_text(text)
    return p


def test_lognormal_draws_follow_the_closed_form(tmp_path):
    # the clip (the type's bounds) cuts 0.08 % below and 0.5 % above: within the KS test's tolerance
    priors, source = load_priors(write(tmp_path, 'source = "s"\n[pothole.radius_m]\nlognormal = [0.25, 0.8]\n'
                                                 'clip = [0.02, 2.0]\n'))
    assert source == "s"
    pothole = get_plugin_manager().get("defect_types", "pothole")
    rng = np.random.default_rng(3)
    radii = np.array([apply_priors(pothole.sample_params(rng), priors["pothole"], rng, "t").radius_m for _ in range(2000)])
    # Kolmogorov-Smirnov against lognormal(median 0.25, sigma 0.8); the type's own draw is uniform 0.10-0.50
    assert stats.kstest(radii, stats.lognorm(s=0.8, scale=0.25).cdf).pvalue > 0.01
    assert (radii > 0.5).mean() == pytest.approx(1 - stats.norm.cdf(math.log(2) / 0.8), abs=0.03)


def test_composed_pothole_models_take_the_prior_size(tmp_path):
    """The generated meshes' footprints, not the drawn numbers: a 1.2-1.3 m prior gives potholes
    whose footprint's equivalent radius is near that, where the type's own draw stays under 0.55 m."""
    pm = get_plugin_manager()
    rules = ComposeRules(type_weights={"pothole": 1.0}, models_per_type=4, seed=5)
    priors, _ = load_priors(write(tmp_path, "[pothole.radius_m]\nuniform = [1.2, 1.3]\n"))

    def radii(library):
        return [math.sqrt(Polygon(m.footprint).area / math.pi) for m in library["pothole"]]

    plain, sized = radii(build_library(rules, pm)), radii(build_library(rules, pm, priors=priors))
    assert max(plain) < 0.6
    assert all(1.0 < r < 1.6 for r in sized), sized


def test_builtin_road_defects_br_priors_hold_the_measured_pothole_sizes():
    priors, source = load_priors("builtin:road_defects_br")
    prior = priors["pothole"]["radius_m"]
    assert prior.kind == "lognormal" and 0.15 < prior.a < 0.4 and prior.clip[1] > 1.0
    assert "train" in source


@pytest.mark.parametrize("text, needle", [
    ("[pothole.radius_m]\nnormal = [1, 2]\n", "pothole.radius_m: give exactly one of"),
    ("[pothole.radius_m]\nlognormal = [-1, 0.5]\n", "median > 0"),
    ("[pothole.radius_m]\nuniform = [2, 1]\n", "lo <= hi"),
    ("[pothole.radius_m]\nuniform = [1]\n", "expected two numbers"),
    ("[pothole.radius_m]\nuniform = [true, 1]\n", "expected two numbers"),
    ("[pothole.radius_m]\nuniform = [0.1, inf]\n", "finite numbers"),
    ("[pothole.radius_m]\nuniform = [0.1, 0.2]\nclip = [0.3, 0.2]\n", "lo <= hi"),
    ("[pothole\n", "not valid TOML"),
])
def test_bad_priors_files_are_one_line(tmp_path, text, needle):
    with pytest.raises(RoadtwinError, match="priors.toml") as e:
        load_priors(write(tmp_path, text))
    assert needle in str(e.value)


def test_a_parameter_the_type_lacks_is_named(tmp_path):
    priors, _ = load_priors(write(tmp_path, "[pothole.width_m]\nuniform = [1, 2]\n"))
    rules = ComposeRules(type_weights={"pothole": 1.0}, models_per_type=1)
    with pytest.raises(RoadtwinError, match="defect type pothole: defect priors name parameters it does not have: width_m"):
        build_library(rules, get_plugin_manager(), priors=priors)


def test_an_integer_parameter_takes_the_rounded_draw():
    crack = get_plugin_manager().get("defect_types", "crack")
    rng = np.random.default_rng(1)
    prior = {"branches": FieldPrior("uniform", 4.6, 5.4)}    # every draw rounds to 5
    drawn = [apply_priors(crack.sample_params(rng), prior, rng, "t").branches for _ in range(50)]
    assert all(type(b) is int and b == 5 for b in drawn)


def test_a_prior_reaching_past_the_parameter_bounds_is_refused_whatever_the_seed(tmp_path):
    """An unclipped lognormal can draw any radius > 0; the pothole's radius_m lies in 0.02..2.0.
    Refused before any draw, not only for the seeds whose draw lands outside."""
    priors, _ = load_priors(write(tmp_path, "[pothole.radius_m]\nlognormal = [0.25, 0.1]\n"))
    rules = ComposeRules(type_weights={"pothole": 1.0}, models_per_type=1)
    with pytest.raises(RoadtwinError, match=r"defect type pothole: defect prior for radius_m draws 0\.\.inf, beyond"):
        build_library(rules, get_plugin_manager(), priors=priors)


def test_a_parameter_that_is_not_a_number_is_refused():
    @dataclass
    class Params:
        shape: str = "round"

    with pytest.raises(RoadtwinError, match="t: defect prior for shape: the parameter is not a number"):
        apply_priors(Params(), {"shape": FieldPrior("uniform", 0.0, 1.0)}, np.random.default_rng(0), "t")


def test_compose_command_refuses_unknown_builtin_priors(tmp_path):
    r = run_cli("compose", "stages/highway.usda", "-o", tmp_path / "out", "--defect-priors", "builtin:nowhere")
    one_line(r, "--defect-priors", "nowhere", "road_defects_br")
    assert not (tmp_path / "out").exists()


def test_compose_names_a_priors_file_type_nobody_registered(tmp_path):
    p = write(tmp_path, 'source = "mine.toml"\n[potholes.radius_m]\nuniform = [0.2, 0.3]\n')
    r = run_cli("compose", "stages/highway.usda", "-o", tmp_path / "out", "--defect-priors", p)
    one_line(r, str(p), "unknown defect types: potholes")
    assert not (tmp_path / "out").exists()


def test_truncated_lognormal_follows_the_closed_form_within_its_ends(tmp_path):
    """``truncate``: the draws keep the lognormal's shape between the ends (KS against the
    truncated closed form), none pile up at an end as ``clip`` makes them."""
    priors, _ = load_priors(write(tmp_path, "[pothole.radius_m]\nlognormal = [0.25, 0.8]\ntruncate = [0.1, 1.2]\n"))
    prior = priors["pothole"]["radius_m"]
    rng = np.random.default_rng(11)
    radii = np.array([prior.draw(rng) for _ in range(3000)])
    base = stats.lognorm(s=0.8, scale=0.25)
    lo, hi = base.cdf(0.1), base.cdf(1.2)
    assert radii.min() >= 0.1 and radii.max() <= 1.2
    assert stats.kstest(radii, lambda x: (base.cdf(x) - lo) / (hi - lo)).pvalue > 0.01
    assert (radii == 0.1).sum() == 0 and (radii == 1.2).sum() == 0


def test_clip_and_truncate_together_are_refused(tmp_path):
    with pytest.raises(RoadtwinError, match="clip or truncate"):
        load_priors(write(tmp_path, "[pothole.radius_m]\nlognormal = [0.25, 0.8]\nclip = [0.1, 1]\ntruncate = [0.1, 1]\n"))
