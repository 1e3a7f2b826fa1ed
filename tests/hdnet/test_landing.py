"""hdnet.landing and the landing table of hd eval: touchdowns, exact probabilities, intervals, ranking."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from hdnet_datasets import SIGMAS_M, build_labelled
from rasterio.transform import Affine
from scipy.special import ndtri

from hdlabels.labeling import label_dataset
from hdlabels.lander import Lander
from hdlabels.settings import LabelSettings
from hdlabels.store import find_labeling, labelings_by_truth
from hdnet.data import split_labels
from hdnet.errors import HdNetError
from hdnet.evaluate import EvalConfig, evaluate_to_report
from hdnet.fit import FitConfig, fit
from hdnet.landing import (
    LandingTally,
    TouchdownScore,
    cell_masses,
    dispersion_weighted,
    exact_safe_probability,
    score_touchdowns,
    touchdown_cells,
    touchdown_offsets,
    truth_clearance_map,
    wilson_interval,
)
from hdnet.landing_table import METHODS, landing_rows, method_map
from hdnet.results import LandingRecord, LandingSettings, SplitInference
from hdnet.sites import SAFETY_INVALID, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_UNSAFE, select_sites
from hdnet.uncertainty import MUTUAL_INFORMATION

SPACING = (1.0, 1.0)
LANDER = Lander()  # the paper's: 10 m diameter


def disk(shape: tuple[int, int], centre: tuple[int, int], radius_m: float) -> np.ndarray:
    """Cells whose centres lie within ``radius_m`` of the centre of cell ``centre`` (1 m cells)."""
    r, c = np.mgrid[: shape[0], : shape[1]]
    return (r - centre[0]) ** 2 + (c - centre[1]) ** 2 <= radius_m**2


def safe_disk_truth(radius_m: float, n: int = 101) -> np.ndarray:
    """A safe disk (label 1) in an unsafe field (label 0), centred on cell (n // 2, n // 2)."""
    return disk((n, n), (n // 2, n // 2), radius_m).astype(np.uint8)


# --- the model ----------------------------------------------------------------------------------
def test_wilson_interval_matches_its_closed_forms():
    z2 = float(ndtri(0.975)) ** 2
    lo, hi = wilson_interval(0, 100)
    assert lo == pytest.approx(0.0, abs=1e-15) and hi == pytest.approx(
        z2 / (100 + z2), rel=1e-12
    )  # the "rule of three" neighbour
    lo, hi = wilson_interval(500, 500)
    assert hi == 1.0 and lo == pytest.approx(500 / (500 + z2), rel=1e-12)  # 0.99238: all 500 safe
    lo, hi = wilson_interval(50, 100)
    half = math.sqrt(z2) * math.sqrt(0.25 / 100 + z2 / (4 * 100**2)) / (1 + z2 / 100)
    assert lo == pytest.approx(0.5 - half, rel=1e-12) and hi == pytest.approx(0.5 + half, rel=1e-12)
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    # 10 safe landings of 10: n / (n + z^2) = 10 / 13.8415 at 95 %, not "certainly safe"
    lo, hi = wilson_interval(10, 10)
    assert lo == pytest.approx(0.7225, abs=5e-5) and hi == pytest.approx(1.0, abs=1e-15)


def test_the_terminal_summary_gives_each_rate_its_interval_and_scenes():
    """``hd eval``'s P(safe landing) lines: per truth a heading with the dispersions, then one line per
    method and test noise level, one cell per dispersion; a method that never landed shows no rate."""
    from hdnet.results import EvaluationResult

    def tally(safe: int, landed: int, scenes: int) -> LandingTally:
        t = LandingTally()
        for k in range(landed):
            t.land(TouchdownScore(1.0 if k < safe else 0.0, 0.0), 5.0, 4.0)
        for _ in range(scenes - landed):
            t.abstain()
        return t

    rows = [
        tally(10, 10, 12).row("base_net", 0.0167, 0.0, "terrain"),
        tally(8, 10, 12).row("base_net", 0.0167, 3.0, "terrain"),
        tally(0, 0, 12).row("uncertainty_aware", 0.0167, 0.0, "terrain"),
        tally(0, 0, 12).row("uncertainty_aware", 0.0167, 3.0, "terrain"),
    ]
    lo8, hi8 = wilson_interval(8, 10)
    assert EvaluationResult([], {}, [], {"bins": 10, "per_sigma": []}, landing=rows).landing_summary().splitlines() == [
        "P(safe landing) against the terrain truth [95 % CI] n=landed/scenes, navigation 1σ 0 | 3 m:",
        f"  base_net               1.67cm  1.000 [0.722, 1.000] n=10/12 | 0.800 [{lo8:.3f}, {hi8:.3f}] n=10/12",
        "  uncertainty_aware      1.67cm  -- n=0/12 | -- n=0/12",
    ]
    assert EvaluationResult([], {}, [], {"bins": 10, "per_sigma": []}).landing_summary() == ""


def test_touchdown_cells_follow_a_north_up_grid():
    offsets = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [-0.49, 0.49], [0.51, -0.51]])
    rows, cols = touchdown_cells(10, 20, offsets, SPACING)
    assert rows.tolist() == [10, 10, 9, 10, 11]  # north is up: a northward touchdown lands a row above
    assert cols.tolist() == [20, 21, 20, 20, 21]
    rows, cols = touchdown_cells(10, 20, np.array([[0.9, 1.0]]), (2.0, 0.5))  # anisotropic cells
    assert (rows[0], cols[0]) == (8, 20)


def test_cell_masses_are_a_discretised_gaussian():
    w = cell_masses(1.5, 1.0)
    assert w.sum() == pytest.approx(1.0, abs=1e-9) and np.allclose(w, w[::-1])  # cut at 6 sigma + 1 cell
    k = len(w) // 2
    assert w[k] == pytest.approx(math.erf(0.5 / (1.5 * math.sqrt(2))), rel=1e-12)  # P(|e| < 0.5 m)
    assert cell_masses(0.0, 1.0).tolist() == [1.0]


def test_a_safe_disk_in_an_unsafe_field_matches_the_analytic_probability():
    """The Monte Carlo lands within its own 95 % interval of the exact value, which itself is the
    Rayleigh probability 1 - exp(-R^2 / 2 sigma^2) up to the disk's pixelation."""
    radius, sigma = 6.0, 3.0
    truth = safe_disk_truth(radius)
    exact = exact_safe_probability(truth, 50, 50, sigma, SPACING)
    rayleigh = 1.0 - math.exp(-(radius**2) / (2 * sigma**2))  # 0.8647
    assert exact == pytest.approx(rayleigh, abs=0.03)
    n = 20_000
    score = score_touchdowns(truth, 50, 50, touchdown_offsets(n, sigma, seed=0, scene=7), SPACING)
    lo, hi = wilson_interval(score.safe * n, n)
    assert lo <= exact <= hi
    assert score.unknown == 0.0
    # a dispersion that reaches the disk's edge from an off-centre aim: lower, and still exact
    off = exact_safe_probability(truth, 50, 54, sigma, SPACING)
    score = score_touchdowns(truth, 50, 54, touchdown_offsets(n, sigma, seed=0, scene=8), SPACING)
    lo, hi = wilson_interval(score.safe * n, n)
    assert off < exact and lo <= off <= hi


def test_no_dispersion_lands_on_the_aim_point():
    truth = safe_disk_truth(3.0)
    assert exact_safe_probability(truth, 50, 50, 0.0, SPACING) == 1.0
    assert exact_safe_probability(truth, 50, 60, 0.0, SPACING) == 0.0
    score = score_touchdowns(truth, 50, 50, touchdown_offsets(100, 0.0, 0, 0), SPACING)
    assert score == TouchdownScore(1.0, 0.0)


def test_touchdowns_off_the_grid_or_unlabelled_are_unknown_and_not_safe():
    truth = np.ones((20, 20), np.uint8)
    truth[:, :5] = 255  # an unlabelled band
    far = np.tile([[-100.0, 0.0]], (10, 1))  # 100 m west: off the grid
    assert score_touchdowns(truth, 10, 10, far, SPACING) == TouchdownScore(0.0, 1.0)
    band = np.tile([[-7.0, 0.0]], (4, 1))
    assert score_touchdowns(truth, 10, 10, band, SPACING) == TouchdownScore(0.0, 1.0)
    assert exact_safe_probability(truth, 10, 1, 0.0, SPACING) == 0.0


def test_touchdowns_are_deterministic_by_seed_and_scene():
    a, b = touchdown_offsets(50, 2.0, 3, 11), touchdown_offsets(50, 2.0, 3, 11)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, touchdown_offsets(50, 2.0, 3, 12))
    assert not np.array_equal(a, touchdown_offsets(50, 2.0, 4, 11))
    assert np.allclose(touchdown_offsets(50, 1.0, 3, 11) * 2.0, a)  # one scene's draws scale with sigma
    big = touchdown_offsets(200_000, 2.0, 0, 0)
    assert np.abs(big.mean(axis=0)).max() < 0.02 and np.allclose(big.std(axis=0), 2.0, rtol=0.01)


def test_truth_clearance_is_the_distance_to_ground_that_is_not_safe():
    truth = safe_disk_truth(6.0)
    c = truth_clearance_map(truth, SPACING)
    assert c[50, 50] == pytest.approx(math.sqrt(37.0))  # the nearest cells outside the disk: (6, 1) away
    assert c[0, 0] == 0.0
    edge = np.ones((5, 5), np.uint8)
    assert truth_clearance_map(edge, SPACING)[2, 2] == 3.0  # outside the grid counts as not safe


def test_dispersion_weighting_is_the_exact_expectation():
    rng = np.random.default_rng(0)
    values = rng.random((30, 30))
    out = dispersion_weighted(values, 2.0, SPACING)
    brute = exact_safe_probability((values > 0.5).astype(np.uint8), 12, 17, 2.0, SPACING)
    assert dispersion_weighted((values > 0.5).astype(float), 2.0, SPACING)[12, 17] == pytest.approx(brute, abs=1e-12)
    assert np.array_equal(dispersion_weighted(values, 0.0, SPACING), values)
    assert out.shape == values.shape


def test_the_tally_counts_abstentions_apart():
    tally = LandingTally()
    tally.abstain()
    tally.land(TouchdownScore(1.0, 0.0), 12.0, 8.0)
    tally.land(TouchdownScore(0.5, 0.25), 6.0, 2.0)
    row = tally.row("base_net", 0.03, 1.0, "terrain")
    assert (row.scenes, row.landed) == (3, 2)
    assert row.p_safe == pytest.approx(0.75) and row.abstain_rate == pytest.approx(1 / 3)
    assert (row.p_safe_low, row.p_safe_high) == wilson_interval(1.5, 2)
    assert row.unknown_fraction == pytest.approx(0.125)
    assert (row.clearance_m, row.truth_clearance_m) == (9.0, 5.0)
    empty = LandingTally()
    empty.abstain()
    row = empty.row("base_net", 0.03, 1.0, "terrain")
    assert math.isnan(row.p_safe) and row.abstain_rate == 1.0


# --- dispersion-aware ranking -----------------------------------------------------------------
def two_regions() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hand-made map: a small safe island of P(safe) 0.99 just larger than the lander, and a wide
    safe field of P(safe) 0.95; unsafe ground between them (also the truth: safe where the map is)."""
    safety = np.full((80, 140), SAFETY_UNSAFE, np.uint8)
    island = disk(safety.shape, (40, 30), 7.0)
    field = np.zeros_like(island)
    field[10:70, 70:130] = True
    safety[island | field] = SAFETY_SAFE
    p = np.where(island, 0.99, np.where(field, 0.95, 0.2))
    return safety, p, (island | field).astype(np.uint8)


def test_dispersion_aware_ranking_prefers_room_to_land():
    safety, p, truth = two_regions()
    zeros = np.zeros(safety.shape, np.float32)
    args = (zeros, zeros, Affine.identity(), SPACING, LANDER, 2)
    aim = select_sites(safety, p, *args)
    assert (aim[0].row, aim[0].col) == (40, 30)  # the aim point's footprint: the island's 0.99 wins
    assert math.isnan(aim[0].touchdown_p_safe) is False and aim[0].touchdown_p_safe == pytest.approx(0.99)
    wide = select_sites(safety, p, *args, nav_sigma_m=3.0)
    best = wide[0]
    assert 10 <= best.row < 70 and 70 <= best.col < 130  # with 3 m of dispersion, the wide field
    assert abs(best.row - 39.5) <= 1 and abs(best.col - 99.5) <= 1  # ... at its centre (clearance)
    assert best.touchdown_p_safe == pytest.approx(0.95, abs=1e-6)
    island_value = dispersion_weighted(np.where(safety == SAFETY_SAFE, p, 0.0), 3.0, SPACING)[40, 30]
    assert island_value < 0.95  # the island loses touchdowns off its edge
    # ... and on the ground the dispersion-aware choice lands safely more often
    p_aim = exact_safe_probability(truth, aim[0].row, aim[0].col, 3.0, SPACING)
    p_wide = exact_safe_probability(truth, best.row, best.col, 3.0, SPACING)
    assert p_wide == pytest.approx(1.0, abs=1e-9) and p_aim < 0.99


def test_a_margin_keeps_only_sites_with_room_around_the_lander():
    """Two safe disks in an unsafe field: radius 6 m (P 0.99) and 8 m (P 0.90). The 10 m lander (radius
    5 m) fits both, and the likelier one wins; with a 2 m margin it needs 7 m of safe ground all round:
    only the wide disk, at its centre; with 4 m (9 m) none; the disk-mean P(safe) stays the body's."""
    shape = (60, 100)
    small, wide = disk(shape, (30, 25), 6.0), disk(shape, (30, 70), 8.0)
    safety = np.full(shape, SAFETY_UNSAFE, np.uint8)
    safety[small | wide] = SAFETY_SAFE
    p = np.where(small, 0.99, np.where(wide, 0.90, 0.1)).astype(np.float32)
    zeros = np.zeros(shape, np.float32)
    args = (zeros, zeros, Affine.identity(), SPACING, LANDER, 3)
    bare = select_sites(safety, p, *args)
    assert (bare[0].row, bare[0].col) == (30, 25) and bare[0].p_safe == pytest.approx(0.99)
    kept = select_sites(safety, p, *args, margin_m=2.0)
    assert [(s.row, s.col) for s in kept] == [(30, 70)]  # 8 - 7 = 1 m of play, less than a site's spacing
    assert kept[0].p_safe == pytest.approx(0.90, rel=1e-6) and kept[0].clearance_m == pytest.approx(math.sqrt(65))
    assert select_sites(safety, p, *args, margin_m=4.0) == []


def test_uncertain_and_invalid_ground_carry_no_touchdown_probability():
    safety, p, _ = two_regions()
    safety[10:70, 70:130][:, ::7] = SAFETY_UNCERTAIN  # stripes of uncertainty through the field
    zeros = np.zeros(safety.shape, np.float32)
    site = select_sites(safety, p, zeros, zeros, Affine.identity(), SPACING, LANDER, 1, nav_sigma_m=3.0)[0]
    assert (site.row, site.col) == (40, 30)  # the field has no whole certain footprint any more
    safety[:] = SAFETY_INVALID
    assert select_sites(safety, p, zeros, zeros, Affine.identity(), SPACING, LANDER, 1, nav_sigma_m=3.0) == []


# --- the landing table ------------------------------------------------------------------------
def fake_inference(truth: np.ndarray) -> SplitInference:
    """Two scenes: one where every method sees the truth, one where the base net is wrong and unsure."""
    n, (h, w) = 2, truth.shape
    label = np.stack([truth.astype(np.int64)] * n)
    prob = np.stack([np.where(truth == 1, 0.9, 0.1)] * n).astype(np.float32)
    prob[1] = np.where(truth == 1, 0.1, 0.9)  # scene 1: the net has safe and unsafe the wrong way round ...
    entropy = np.full((n, h, w), 0.1, np.float32)
    entropy[1] = 0.6  # ... and is unsure everywhere
    base = np.stack([np.where(truth == 1, 0.8, 0.2)] * n).astype(np.float32)
    base[:, :5], base[:, -5:], base[:, :, :5], base[:, :, -5:] = np.nan, np.nan, np.nan, np.nan  # the border band
    z = np.zeros((n, h, w), np.float32)
    return SplitInference(
        0.03,
        np.array([4, 9]),
        label,
        np.zeros((n, h, w), bool),
        prob,
        (prob >= 0.5).astype(np.int64),
        entropy,
        base >= 0.5,
        z,
        z,
        base,
    )


def test_landing_rows_score_each_method_against_each_truth():
    truth = safe_disk_truth(12.0, n=61)
    inf = fake_inference(truth)
    shifted = np.roll(truth, 20, axis=1)  # a second truth that disagrees
    truths = {"terrain": {4: truth, 9: truth}, "clean-scan": {4: shifted, 9: shifted}}
    rows = landing_rows(inf, 0.5, truths, LANDER, 1.0, LandingSettings(nav_sigmas_m=(0.0, 2.0), touchdowns=400))
    by = {(r.truth, r.method, r.nav_sigma_m): r for r in rows}
    assert len(rows) == 2 * len(METHODS) * 2 and all(r.scenes == 2 for r in rows)
    ua = by[("terrain", "uncertainty_aware", 0.0)]
    assert ua.landed == 1 and ua.abstain_rate == 0.5 and ua.p_safe == 1.0  # scene 1: all uncertain -> abstains
    net = by[("terrain", "base_net", 0.0)]
    assert net.landed == 2 and net.p_safe == 0.5  # scene 1: it lands where it wrongly sees safe ground
    assert by[("terrain", "alhat_baseline", 2.0)].p_safe == pytest.approx(1.0)  # 12 m of room, 2 m of dispersion
    assert by[("clean-scan", "alhat_baseline", 0.0)].p_safe == 0.0  # the same site, judged by another truth
    assert by[("terrain", "alhat_baseline", 0.0)].truth_clearance_m == pytest.approx(math.sqrt(145.0))  # (12, 1)


def test_the_uncertainty_aware_landing_thresholds_the_score_it_is_given():
    """Scene 0 sure of itself (H 0.1) but its samples disagree (MI 0.55); scene 1 unsure (H 0.6) with
    samples that agree (MI 0.05): on the mutual information at H_t 0.5 the uncertainty-aware map
    abstains in scene 0 and lands in scene 1 where the base net wrongly sees safe ground."""
    truth = safe_disk_truth(12.0, n=61)
    inf = fake_inference(truth)
    with pytest.raises(HdNetError, match="holds no mutual information"):
        method_map("uncertainty_aware", inf, 0, 0.5, MUTUAL_INFORMATION)
    mi = np.full(inf.entropy_nats.shape, 0.05, np.float32)
    mi[0] = 0.55
    inf = dataclasses.replace(inf, mutual_information_nats=mi)
    safety, _ = method_map("uncertainty_aware", inf, 0, 0.5, MUTUAL_INFORMATION)
    assert set(np.unique(safety)) == {SAFETY_UNCERTAIN, SAFETY_INVALID}
    safety, _ = method_map("uncertainty_aware", inf, 1, 0.5, MUTUAL_INFORMATION)
    np.testing.assert_array_equal(safety, method_map("base_net", inf, 1, 0.5)[0])
    truths = {"terrain": {4: truth, 9: truth}}
    settings = LandingSettings(nav_sigmas_m=(0.0,), touchdowns=400)
    (on_entropy,) = landing_rows(inf, 0.5, truths, LANDER, 1.0, settings, methods=("uncertainty_aware",))
    (on_mi,) = landing_rows(
        inf, 0.5, truths, LANDER, 1.0, settings, methods=("uncertainty_aware",), uncertainty=MUTUAL_INFORMATION
    )
    assert (on_entropy.landed, on_entropy.p_safe) == (1, 1.0)  # scene 0 lands on safe ground, scene 1 abstains
    assert (on_mi.landed, on_mi.abstain_rate, on_mi.p_safe) == (1, 0.5, 0.0)  # scene 0 abstains, scene 1 is wrong


def test_method_maps_use_the_baseline_band_as_invalid():
    truth = safe_disk_truth(12.0, n=61)
    inf = fake_inference(truth)
    for method in METHODS:
        safety, _ = method_map(method, inf, 1, 0.5)
        assert (safety[:5] == SAFETY_INVALID).all()
    assert (method_map("uncertainty_aware", inf, 1, 0.5)[0][10:-10, 10:-10] == SAFETY_UNCERTAIN).all()
    net = method_map("base_net", inf, 1, 0.5)[0][5:-5, 5:-5]
    inside = truth[5:-5, 5:-5] == 1
    assert (net[inside] == SAFETY_UNSAFE).all() and (net[~inside] == SAFETY_SAFE).all()


@pytest.fixture(scope="module")
def two_truths(tmp_path_factory):
    root = tmp_path_factory.mktemp("landing")
    dataset = build_labelled(root / "data")
    label_dataset(dataset, LabelSettings(truth="terrain"), workers=1)
    run = root / "run"
    names = labelings_by_truth(dataset, find_labeling(dataset, _clean_name(dataset)))
    fit(dataset, run, FitConfig(profile="tiny", epochs=1, progress=False, labels=names["terrain"]))
    return dataset, run, names


def _clean_name(dataset) -> str:
    from lidarsim.shards import read_manifest

    return next(
        lab["name"] for lab in read_manifest(dataset)["labelings"] if lab.get("truth", "clean-scan") == "clean-scan"
    )


def test_eval_reports_landing_against_both_truths(two_truths, tmp_path):
    dataset, run, names = two_truths
    assert set(names) == {"clean-scan", "terrain"}
    out = tmp_path / "report"
    cfg = EvalConfig(mc_samples=2, labels=names["terrain"], nav_sigma_m=(2.0, 0.0, 2.0))
    assert cfg.nav_sigma_m == (0.0, 2.0)
    result = evaluate_to_report(run, dataset, out, cfg)
    report = json.loads((out / "report.json").read_text())
    rows = report["landing"]
    assert {(r["truth"], r["method"], r["test_sigma_m"], r["nav_sigma_m"]) for r in rows} == {
        (t, m, s, n) for t in ("terrain", "clean-scan") for m in METHODS for s in SIGMAS_M for n in (0.0, 2.0)
    }
    assert report["landing_settings"]["labelings"] == names
    n_test = result.run["test_scans"]
    assert all(r["scenes"] == n_test for r in rows)
    # the baseline at no dispersion, by hand: its best site per scene from the label shard's P(safe)
    clean = split_labels(dataset, "test", names["clean-scan"])
    terrain = split_labels(dataset, "test", names["terrain"])
    inf = result.test[SIGMAS_M[0]]
    safe_at_site: dict[str, list[bool]] = {"terrain": [], "clean-scan": []}
    assert inf.baseline_p_safe is not None
    for j, scan in enumerate(inf.scan_index):
        safety, p = method_map("alhat_baseline", inf, j, math.inf)
        sites = select_sites(
            safety, p, inf.entropy_nats[j], inf.baseline_p_safe[j], Affine.identity(), SPACING, LANDER, 1
        )
        if sites:
            safe_at_site["terrain"].append(terrain[int(scan)][sites[0].row, sites[0].col] == 1)
            safe_at_site["clean-scan"].append(clean[int(scan)][sites[0].row, sites[0].col] == 1)
    for truth, hits in safe_at_site.items():
        row = next(
            r
            for r in rows
            if (r["truth"], r["method"], r["test_sigma_m"], r["nav_sigma_m"])
            == (truth, "alhat_baseline", SIGMAS_M[0], 0.0)
        )
        assert row["landed"] == len(hits)
        assert row["p_safe"] == (pytest.approx(np.mean(hits)) if hits else None)
    md = (out / "report.md").read_text()
    assert "## Landing outcome (test split)" in md and "### Against the terrain truth" in md
    assert (out / "landing.png").read_bytes()[:4] == b"\x89PNG"


def test_eval_says_when_the_terrain_truth_is_missing(tmp_path):
    dataset = build_labelled(tmp_path / "data", n_scans=10)
    run = tmp_path / "run"
    fit(dataset, run, FitConfig(profile="tiny", epochs=1, progress=False))
    out = tmp_path / "report"
    evaluate_to_report(run, dataset, out, EvalConfig(mc_samples=2, nav_sigma_m=(1.0,)))
    report = json.loads((out / "report.json").read_text())
    assert {r["truth"] for r in report["landing"]} == {"clean-scan"}
    assert report["landing_settings"]["missing_truths"] == ["terrain"]
    assert "`hd label DATASET --truth terrain` adds the terrain's" in (out / "report.md").read_text()


def test_the_landing_figure_draws_rates_at_the_ends_and_methods_that_never_landed(tmp_path):
    """A rate of 1 whose Wilson end rounds a hair below it, and a method that abstained everywhere
    (no rate), are drawn without error."""
    from hdnet.figures import landing_figure
    from hdnet.results import EvaluationResult, LandingRow

    def row(method: str, nav: float, p: float, lo: float, hi: float, landed: int) -> LandingRow:
        return LandingRow(method, 0.03, nav, "terrain", 500, landed, p, lo, hi, 0.0, 0.0, 0.0, 0.0, 10.0, 9.0)

    rows = [
        row("uncertainty_aware", 0.0, 1.0, 0.9924, 1.0 - 1e-16, 500),
        row("uncertainty_aware", 1.0, 0.998, 0.99, 0.999, 500),
        row("base_net", 0.0, math.nan, math.nan, math.nan, 0),
        row("base_net", 1.0, math.nan, math.nan, math.nan, 0),
    ]
    result = EvaluationResult([], {}, [], {"bins": 10, "per_sigma": []}, landing=rows)
    landing_figure(result, tmp_path / "landing.png")
    assert (tmp_path / "landing.png").read_bytes()[:4] == b"\x89PNG"


def test_the_landing_record_is_written_as_report_json_holds_it_and_read_back():
    """report.json's landing_settings: the settings' keys, then the labellings and the missing truths,
    in that order; read back to the same record; a margin and missing truths only when there are any."""
    record = LandingRecord(LandingSettings((0.0, 2.0), 500, 3, 2.5), {"clean-scan": "paper-x"}, ("terrain",))
    written = json.loads(json.dumps(record.to_dict()))
    assert list(written) == ["nav_sigmas_m", "touchdowns", "seed", "site_margin_m", "labelings", "missing_truths"]
    assert LandingRecord.from_dict(written) == record
    plain = LandingRecord(LandingSettings())
    assert plain.to_dict() == {"nav_sigmas_m": [0.0, 1.0, 3.0], "touchdowns": 1000, "seed": 0}
    assert LandingRecord.from_dict(plain.to_dict()) == plain
    with pytest.raises(KeyError):
        LandingRecord.from_dict({"seed": 0})
