"""Tests of experiments/: the shared runner and the configurations of the per-table scripts.

The scripts live outside the package (``python experiments/table5_compactness.py``) and import their
sibling ``runner``; the tests import them the same way, with ``experiments/`` on the path.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"
sys.path.insert(0, str(EXPERIMENTS))

import airplane_engines  # noqa: E402
import fig8_supervision as fig8  # noqa: E402
import fig9_nearest_surface as fig9  # noqa: E402
import fig10_compactness as fig10  # noqa: E402
import fig11_point_density as fig11  # noqa: E402
import paper_vs_code  # noqa: E402
import command_line  # noqa: E402
import compactness_scale  # noqa: E402
import runner  # noqa: E402
import segmentation_errors  # noqa: E402
import summaries  # noqa: E402
import table1_2_comparison as table12  # noqa: E402
import table3_supervision as table3  # noqa: E402
import table4_distance as table4  # noqa: E402
import table5_compactness as table5  # noqa: E402
import table6_num_cuboids as table6  # noqa: E402

from cuboidlib.abstraction import AbstractionBatch  # noqa: E402
from cuboidlib.dataset import ShapeSet  # noqa: E402
from cuboidlib.geometry import Cuboids  # noqa: E402
from cuboidlib.losses import LossConfig  # noqa: E402
from cuboidlib.train_config import TrainConfig  # noqa: E402

SCRIPTS = (table3, table4, table5, table6, fig8, fig9, fig10, fig11, table12, paper_vs_code)


pytestmark = pytest.mark.usefixtures("cache_dir", "restore_threads")


def _runs(module, *argv: str) -> tuple[runner.Scale, list[runner.Run]]:
    """The runs a script would do for ``argv`` (nothing is trained)."""
    args = module.EXPERIMENT.parser().parse_args(list(argv))
    scale = command_line.scale_from_args(args, module.EXPERIMENT)
    return scale, module.EXPERIMENT.build_runs(scale, args)


def _keys(runs, *fields) -> set[tuple]:
    return {tuple(r.key[f] for f in fields) for r in runs}


# ----------------------------------------------------------------------------------------------
# Course scale
# ----------------------------------------------------------------------------------------------


# The committed recipe's per-category choices (data_samples/checkpoints/README.md, "The recipe"): animal tails hold about 26 of 1024 points;
# airplanes use fewer cuboids than the paper's 11.8 with lambda_1 = 0.02, and their engines get no cuboid with 0.005
EXISTENCE_MIN_POINTS = {"airplane": 24, "chair": 24, "table": 24, "animal": 8}
LAMBDA_COMPACT = {"airplane": 0.001, "chair": 0.02, "table": 0.02, "animal": 0.02}


def test_course_scale_is_the_configuration_of_the_committed_checkpoints():
    for category, m in (("airplane", 20), ("chair", 16), ("table", 14), ("animal", 16)):
        c = runner.course_config(category, steps=300)
        assert (c.n_shapes, c.n_points, c.batch_size, c.lr, c.max_steps, c.num_threads) == (1000, 1024, 16, 2e-3, 300, 1)
        assert c.model_config.attention_scale and c.loss_config.centers_from_allocation
        assert c.max_minutes is None and c.checkpoint_every == 300 and c.validate_every == 100
        assert c.model_config.num_cuboids == m and c.model_config.global_dim == 256  # ModelConfig.small
        assert c.loss_config.compactness_average and c.loss_config.lambda_compact == LAMBDA_COMPACT[category]
        assert c.loss_config.existence_min_points == EXISTENCE_MIN_POINTS[category]
        stored = TrainConfig.load_json(ROOT / "data_samples" / "checkpoints" / "configs" / f"{category}.json")
        budget = ("max_steps", "max_minutes", "checkpoint_every", "validate_every")
        assert c.replace(**{k: getattr(stored, k) for k in budget}) == stored, f"{category}: differs from its config"


def test_quick_scale_uses_the_tiny_network_and_fewer_points():
    quick = runner.Scale(quick=True, steps=2, n_shapes=12, seeds=(0,))
    c = quick.config("chair", seed=3, n_points=4096, model={"num_cuboids": 8})
    assert (c.n_points, c.n_shapes, c.max_steps, c.seed, c.batch_size) == (512, 12, 2, 3, 4)
    assert c.model_config.global_dim == 16 and c.model_config.num_cuboids == 8
    assert quick.points(256) == 32 and runner.Scale(False, 10, 256, (0,)).points(256) == 256


def test_compactness_figures_show_why_the_literal_sum_collapses():
    f = compactness_scale.compactness_figures("chair", n_shapes=4, n_points=128)
    lit, avg, m = f["literal"], f["averaged"], f["M"]
    for k in lit:  # the averaged form is Eq. (6) divided by M^2
        assert avg[k] == pytest.approx(lit[k] / m**2, rel=1e-9)
    # by hand: equal shares 1/k on k of M cuboids, lambda 0.1, eps 0.01
    assert lit[2] == pytest.approx(0.1 * (2 * math.sqrt(0.5 + 0.01) + (m - 2) * 0.1) ** 2)
    assert lit[2] - lit[1] > f["one_box"] > avg[2] - avg[1] > 0  # a 2nd cuboid: too dear literally, affordable averaged
    assert "collapses" in compactness_scale.compactness_note("chair")


# ----------------------------------------------------------------------------------------------
# Noise (Table 4)
# ----------------------------------------------------------------------------------------------


def test_noise_is_seeded_isotropic_and_has_the_requested_standard_deviation():
    points = torch.zeros(64, 1024, 3)
    a = runner.add_noise(points, 0.02, seed=7)
    assert torch.equal(a, runner.add_noise(points, 0.02, seed=7))
    assert not torch.equal(a, runner.add_noise(points, 0.02, seed=8))
    e = a.reshape(-1, 3).double()
    n = e.shape[0]
    assert e.std(dim=0).sub(0.02).abs().max() < 0.01 * 0.02  # per coordinate, sd error ~ 0.2 %
    assert e.mean(dim=0).abs().max() < 5 * 0.02 / math.sqrt(n)
    cov = (e.T @ e) / n
    off_diagonal = cov - torch.diag(torch.diag(cov))
    assert off_diagonal.abs().max() < 0.02 * 0.02**2  # isotropic: no correlation between coordinates
    # the same draw at every level: sigma 0.01 is exactly half of sigma 0.02
    torch.testing.assert_close(runner.add_noise(points, 0.01, seed=7), a / 2)
    assert torch.equal(runner.add_noise(points + 1, 0.0, seed=7), points + 1)


def test_noisy_splits_jitter_only_the_positions_with_one_seed_per_split():
    shapes = ShapeSet(torch.zeros(3, 50, 3), torch.nn.functional.normalize(torch.ones(3, 50, 3), dim=-1),
                      torch.zeros(3, 50, dtype=torch.long), torch.arange(3))
    noisy = runner.noisy_splits({"train": shapes, "val": shapes, "test": shapes}, 0.03, data_seed=0)
    assert not torch.equal(noisy["train"].points, noisy["test"].points)
    for split in noisy.values():
        assert torch.equal(split.normals, shapes.normals) and torch.equal(split.labels, shapes.labels)
        assert not torch.equal(split.points, shapes.points)
    assert torch.equal(runner.noisy_splits({"test": shapes}, 0.03, 0)["test"].points, noisy["test"].points)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"sigma_n": -0.1}, "sigma_n must be a finite non-negative"),
        ({"sigma_n": float("nan")}, "sigma_n must be a finite non-negative"),
        ({"seed": -1}, "seed must be a non-negative integer"),
        ({"points": torch.zeros(4, 2)}, r"points must be a float tensor of shape \(\.\.\., 3\)"),
    ],
)
def test_noise_rejects_bad_arguments(kwargs, match):
    args = {"points": torch.zeros(4, 3), "sigma_n": 0.01, "seed": 0, **kwargs}
    with pytest.raises(ValueError, match=match):
        runner.add_noise(**args)


# ----------------------------------------------------------------------------------------------
# Pieces of the runner
# ----------------------------------------------------------------------------------------------


def test_nearest_cuboid_segmentation_picks_the_nearest_existing_cuboid():
    # two unit cubes centred at x = -2 and x = +2, a third at the origin that does not exist
    centers = torch.tensor([[[-2.0, 0, 0], [2.0, 0, 0], [0.0, 0, 0]]])
    quats = torch.tensor([[1.0, 0, 0, 0]]).expand(1, 3, 4)
    half = torch.full((1, 3, 3), 0.5)
    exists = torch.tensor([[True, True, False]])
    points = torch.tensor([[[-2.5, 0, 0], [2.5, 0.1, 0], [0.4, 0, 0], [-0.4, 0, 0]]])
    # the inner points face the cube they belong to: Eq. (5) measures to the face whose normal matches
    normals = torch.tensor([[[-1.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0], [1.0, 0, 0]]])
    shapes = ShapeSet(points, normals, None, torch.arange(1))
    pred = AbstractionBatch(Cuboids(centers, quats, half, exists), torch.zeros(1, 4, dtype=torch.long))
    everything = AbstractionBatch(Cuboids(centers, quats, half, torch.ones(1, 3, dtype=torch.bool)), pred.labels)
    for distance in ("normal", "nearest_surface"):
        # by hand: x = 0.4 is 1.1 from cube 1 (its -x face at 1.5), 1.9 or 2.9 from cube 0, 0.1 or 0.9 from cube 2
        assert torch.equal(runner.nearest_cuboid_segmentation(shapes, pred, distance), torch.tensor([[0, 1, 1, 0]]))
        assert torch.equal(runner.nearest_cuboid_segmentation(shapes, everything, distance), torch.tensor([[0, 1, 2, 2]]))
    with pytest.raises(ValueError, match="segmentation distance must be"):
        runner.nearest_cuboid_segmentation(shapes, pred, "chamfer")


def test_summary_gives_mean_and_sample_sd_over_seeds():
    rows = [{"lambda_1": 0.1, "seed": s, "method": "network", "cd": v, "miou": None} for s, v in enumerate((1.0, 2.0, 6.0))]
    rows.append({"lambda_1": 0.2, "seed": 0, "method": "network", "cd": 5.0, "miou": 0.5})
    first, second = runner.summarize(rows, ("lambda_1",), ("cd", "miou"))
    assert first["lambda_1"] == 0.1 and first["seeds"] == [0, 1, 2]
    assert first["cd_mean"] == pytest.approx(3.0) and first["cd_sd"] == pytest.approx(math.sqrt(7.0))  # (4+1+9)/2
    assert first["miou_mean"] is None and first["miou_n"] == 0
    assert second["cd_sd"] is None and runner.mean_sd(second, "cd", 1000, 1) == "5000.0"
    assert runner.mean_sd(first, "cd", 2, 2) == "6.00 ± 5.29"


def test_estimated_wall_time_spreads_the_runs_over_the_jobs():
    scale = runner.Scale(False, 100, 256, (0,))
    runs = [runner.Run(f"r{i}", {"i": i}, scale.config("chair", model={"num_cuboids": m}))
            for i, m in enumerate((8, 16, 24))]
    each = [runner.estimate_seconds(r) for r in runs]
    assert each[0] < each[1] < each[2]  # more cuboids, slower steps
    assert runner.estimate_makespan(runs, 1) == pytest.approx(sum(each))
    assert runner.estimate_makespan(runs, 2) == pytest.approx(max(each[2], each[0] + each[1]))
    assert runner.estimate_makespan(runs, 3) == pytest.approx(max(each))


# ----------------------------------------------------------------------------------------------
# The runs of every script
# ----------------------------------------------------------------------------------------------


def test_table3_runs_the_three_supervisions_on_three_categories():
    _, runs = _runs(table3)
    assert _keys(runs, "category", "variant") == {(c, v) for c in ("chair", "table", "airplane")
                                                  for v in ("P2C-Dis", "Chamfer-Dis", "P2C-Seg")}
    assert len(runs) == 9 and all(r.config.max_steps == 600 and r.config.loss_config.lambda_compact == 0 for r in runs)
    by = {r.key["variant"]: r for r in runs}
    assert by["P2C-Dis"].config.loss_config.allocation == "nearest_cuboid"
    assert by["Chamfer-Dis"].config.loss_config.distance == "chamfer"
    p2c = by["P2C-Seg"].config.loss_config
    assert (p2c.distance, p2c.allocation) == ("normal", "segmentation") and "segmentation" not in by["P2C-Seg"].options
    assert (by["P2C-Dis"].options["segmentation"], by["Chamfer-Dis"].options["segmentation"]) == ("normal",
                                                                                                   "nearest_surface")


def test_table3_places_the_cuboids_of_the_variants_without_a_segmentation_branch_as_asked():
    """Under the recipe every variant takes the centroids of the segmentation branch's allocation as positions;
    --predicted-positions gives P2C-Dis and Chamfer-Dis the predicted translation, and P2C-Seg keeps the recipe's."""
    _, runs = _runs(table3, "--categories", "chair")
    assert {r.key["variant"]: r.config.loss_config.centers_from_allocation for r in runs} == {
        "P2C-Dis": True, "Chamfer-Dis": True, "P2C-Seg": True}, "the recipe's positions, as the committed runs"
    _, runs = _runs(table3, "--categories", "chair", "--predicted-positions")
    assert {r.key["variant"]: r.config.loss_config.centers_from_allocation for r in runs} == {
        "P2C-Dis": False, "Chamfer-Dis": False, "P2C-Seg": True}
    _, subset = _runs(table3, "--variants", "P2C-Dis,Chamfer-Dis", "--predicted-positions", "--seeds", "3")
    assert _keys(subset, "variant") == {("P2C-Dis",), ("Chamfer-Dis",)} and len(subset) == 3 * 2 * 3
    loss = subset[0].config.loss_config
    assert (loss.allocation, loss.centers_from_allocation) == ("nearest_cuboid", False)


def test_table4_crosses_four_noise_levels_with_four_distances():
    _, runs = _runs(table4)
    assert len(runs) == 16 and {r.config.category for r in runs} == {"chair"}
    assert _keys(runs, "sigma_n", "distance", "sigma_s") == {
        (n, d, s) for n in (0.0, 0.01, 0.02, 0.03) for d, s in (("Distance", 0.0), ("Normal", 0.0), ("Normal", 0.025),
                                                                ("Normal", 0.05))}
    for r in runs:
        loss = r.config.loss_config
        assert r.options["sigma_n"] == r.key["sigma_n"] and loss.sigma_s == r.key["sigma_s"]
        assert loss.distance == ("nearest_surface" if r.key["distance"] == "Distance" else "normal")


def test_table5_has_exactly_the_four_lambdas_with_three_seeds():
    _, runs = _runs(table5)
    assert sorted({r.key["lambda_1"] for r in runs}) == [0.0, 0.05, 0.1, 0.2]
    assert len(runs) == 12 and {r.key["seed"] for r in runs} == {0, 1, 2}
    for r in runs:
        assert r.config.loss_config.lambda_compact == r.key["lambda_1"] and r.config.loss_config.compactness_average
        assert r.config.seed == r.key["seed"]
    _, quick = _runs(table5, "--quick", "--with-sum-form")
    assert len(quick) == 5
    assert [r.config.loss_config.compactness_average for r in quick if r.key["form"] == "sum"] == [False]


@pytest.mark.parametrize("module, argv, n_runs, changed", [
    (table3, ("--categories", "chair"), 9, lambda c: (c.loss_config.allocation, c.loss_config.distance,
                                                      c.loss_config.lambda_compact)),
    (table4, ("--noise", "0,0.03", "--columns", "Normal-0,Normal-0.05"), 12,
     lambda c: (c.loss_config.distance, c.loss_config.sigma_s)),
    (table6, ("--categories", "chair"), 15, lambda c: c.model_config.num_cuboids),
])
def test_the_15_minute_ablations_change_both_stages_alike(module, argv, n_runs, changed):
    """Tables 3, 4 and 6 at the 15-minute recipe's scale (experiments/ablations_15min.sh): each cell's change
    reaches both stages, which are otherwise the pinned recipe's."""
    _, runs = _runs(module, "--recipe", "15min", "--seeds", "3", *argv)
    assert len(runs) == n_runs and len({r.name for r in runs}) == n_runs
    first, second = runner.recipe_configs("chair", runner.FIFTEEN_MINUTE_STEPS)
    for r in runs:
        assert r.finetune is not None and changed(r.config) == changed(r.finetune)
        assert r.config.n_shapes == first.n_shapes and r.finetune.max_steps == second.max_steps
    assert len({tuple(sorted((k, v) for k, v in r.key.items() if k != "seed")) for r in runs}) == n_runs // 3


def test_table4_takes_a_subset_of_its_rows_and_columns():
    _, runs = _runs(table4, "--noise", "0.03", "--columns", "Distance")
    assert _keys(runs, "sigma_n", "distance", "sigma_s") == {(0.03, "Distance", 0.0)}
    for bad in (["--noise", "0.5"], ["--columns", "Normal-0.1"], ["--noise", "x"]):
        with pytest.raises(SystemExit):
            table4.EXPERIMENT.parser().parse_args(bad)


def test_table5_at_the_15_minute_recipes_scale_trains_both_stages_with_each_lambda():
    scale, runs = _runs(table5, "--recipe", "15min")
    assert (scale.steps, scale.n_shapes, scale.recipe) == (runner.FIFTEEN_MINUTE_STEPS, 1000, "15min")
    recipe = runner.RECIPE_DIR
    first, second = TrainConfig.load_json(recipe / "chair.json"), TrainConfig.load_json(recipe / "finetune" / "chair.json")
    assert len(runs) == 12
    for r in runs:
        lam, seed = r.key["lambda_1"], r.key["seed"]
        for stage, stored in ((r.config, first), (r.finetune, second)):
            assert stage.loss_config.lambda_compact == lam and stage.seed == seed
            assert stage.max_minutes is None and stage.num_threads == 1 and stage.init_from is None
            # nothing else differs from the recipe's stage but the budget, seed and lambda_1
            same = stage.replace(loss={"lambda_compact": stored.loss_config.lambda_compact}, seed=stored.seed,
                                 max_steps=stored.max_steps, max_minutes=stored.max_minutes,
                                 num_threads=stored.num_threads, init_from=stored.init_from,
                                 checkpoint_every=stored.checkpoint_every)
            assert same == stored
        assert r.config.max_steps == runner.FIFTEEN_MINUTE_STEPS and r.finetune.max_steps == second.max_steps
    # a second stage changes what is trained, so the trainings are not the course scale's
    _, course = _runs(table5)
    assert not {runner.training_key(r) for r in runs} & {runner.training_key(r) for r in course}
    assert all(r.finetune is None for r in course)
    with pytest.raises(ValueError, match="second stage"):
        runner.Run("x", {}, runs[0].config, task="score", finetune=runs[0].finetune)


def test_a_quick_two_stage_run_scores_the_second_stages_weights(tmp_path):
    code = command_line.main(table5.EXPERIMENT, ["--recipe", "15min", "--quick", "--jobs", "1", "--out", str(tmp_path),
                                           "--runs-dir", str(tmp_path / "runs")])
    assert code == 0
    data = json.loads((tmp_path / "table5_compactness_15min_quick.json").read_text())
    assert data["settings"]["recipe"] == "15min" and data["settings"]["finetune_steps"] == 2
    for record in data["runs"]:
        assert record["training"]["steps"] == 2 and record["training"]["finetune_steps"] == 2
        assert Path(record["checkpoint"]).parent.name == "finetune" and Path(record["checkpoint"]).is_file()
        assert record["finetune_config"]["loss"]["lambda_compact"] == record["key"]["lambda_1"]
    # --resume reads every finished run back
    code = command_line.main(table5.EXPERIMENT, ["--recipe", "15min", "--quick", "--jobs", "1", "--out", str(tmp_path),
                                           "--runs-dir", str(tmp_path / "runs"), "--resume"])
    again = json.loads((tmp_path / "table5_compactness_15min_quick.json").read_text())
    assert code == 0 and again["settings"]["reused_runs"] == 4


def test_paper_vs_code_goes_from_the_printed_losses_to_the_authors_code_one_change_at_a_time():
    _, runs = _runs(paper_vs_code)
    assert len(runs) == 8 and {r.key["seed"] for r in runs} == {0, 1}
    losses = {r.key["variant"]: r.config.loss_config for r in runs if r.key["seed"] == 0}
    assert list(losses) == [name for name, _ in paper_vs_code.VARIANTS]
    # The first is the paper exactly, the last the authors' code exactly (with the shared lambda_1 = 0.1).
    assert losses["paper"] == LossConfig()
    assert losses["authors' code"] == LossConfig.authors_code()
    changed = [{f for f in paper_vs_code.PAPER_LOSS if getattr(a, f) != getattr(b, f)}
               for a, b in zip(list(losses.values()), list(losses.values())[1:])]
    assert changed == [{"compactness_average"}, {"existence_min_points"}, {"centers_from_allocation"}]
    assert len({r.config.replace(loss={}, seed=0).model_config for r in runs}) == 1  # one network for all


def test_table6_sweeps_the_number_of_cuboids_on_three_categories():
    _, runs = _runs(table6, "--seeds", "2")
    assert _keys(runs, "category", "M") == {(c, m) for c in ("chair", "table", "airplane") for m in (8, 12, 16, 20, 24)}
    assert len(runs) == 30 and all(r.config.model_config.num_cuboids == r.key["M"] for r in runs)
    _, chairs = _runs(table6, "--categories", "chair")
    assert {r.config.category for r in chairs} == {"chair"} and len(chairs) == 5


def test_fig11_trains_with_three_densities_scored_against_the_densest():
    _, runs = _runs(fig11)
    assert [r.config.n_points for r in runs] == [256, 1024, 4096]
    assert all(r.options["reference_points"] == 4096 and r.config.category == "chair" for r in runs)


def test_figs_8_to_10_train_their_tables_configurations():
    _, t3 = _runs(table3, "--categories", "chair")
    _, t4 = _runs(table4)
    _, t5 = _runs(table5)
    _, f8 = _runs(fig8)
    _, f9 = _runs(fig9)
    _, f10 = _runs(fig10)
    configs = lambda runs: [(r.name, r.config.to_dict(), r.options) for r in runs]  # noqa: E731
    assert configs(f8) == configs(t3), "Fig. 8: Table 3's chair runs"
    assert configs(f9) == configs([r for r in t4 if r.key["sigma_n"] == 0.0 and r.key["distance"] == "Distance"]
                                  + [r for r in t4 if r.key["sigma_n"] == 0.0 and r.key["sigma_s"] == 0.05])
    assert configs(f10) == configs([r for r in t5 if r.key["seed"] == 0]), "Fig. 10: Table 5's first seed"


def test_thickness_is_the_median_smallest_over_largest_half_size():
    half_sizes = torch.tensor([[[0.5, 0.5, 0.5], [0.01, 0.5, 0.4], [0.1, 0.2, 0.4]],
                               [[0.2, 0.2, 0.02], [0.3, 0.3, 0.3], [0.3, 0.3, 0.3]]])
    exists = torch.tensor([[True, True, True], [True, False, False]])
    cuboids = Cuboids(torch.zeros(2, 3, 3), torch.tensor([1.0, 0, 0, 0]).expand(2, 3, 4), half_sizes, exists)
    pred = AbstractionBatch(cuboids, torch.zeros(2, 4, dtype=torch.long))
    # shape 0: ratios 1, 0.02, 0.25 -> median 0.25; shape 1: only the plate, 0.1
    assert runner.thickness(pred) == pytest.approx((0.25 + 0.1) / 2)


def test_records_written_before_the_rename_give_their_flatness_as_thickness():
    record = {"status": "ok", "key": {"seed": 0}, "results": [{"method": "network", "metrics": {"cd": 1.0, "flatness": 0.3}}]}
    assert runner.result_rows([record]) == [{"seed": 0, "method": "network", "cd": 1.0, "thickness": 0.3}]
    both = {"cd": 1.0, "flatness": 0.3, "thickness": 0.4}
    assert summaries.current_metrics(both) == {"cd": 1.0, "thickness": 0.4}, "today's name wins"
    committed = [EXPERIMENTS / "results" / f"{name}.json" for name in ("table3_supervision", "fig9_nearest_surface")]
    assert all("flatness" not in path.read_text() for path in committed), "the committed results use today's name"


def test_fig9_quick_draws_both_distances(tmp_path):
    code = command_line.main(fig9.EXPERIMENT, ["--quick", "--jobs", "1", "--out", str(tmp_path), "--runs-dir",
                                         str(tmp_path / "runs")])
    assert code == 0
    data = json.loads((tmp_path / "fig9_nearest_surface_quick.json").read_text())
    assert [r["key"]["distance"] for r in data["runs"]] == ["Distance", "Normal"]
    assert all(0 < r["results"][0]["metrics"]["thickness"] <= 1 for r in data["runs"])
    assert (tmp_path / "fig9_nearest_surface_quick.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_tables_1_2_compare_three_methods_on_four_categories():
    _, runs = _runs(table12)
    assert _keys(runs, "category") == {("airplane",), ("chair",), ("table",), ("animal",)}
    train = [r for r in runs if r.task == "train"]
    fits = [r for r in runs if r.task == "fit"]
    assert len(train) == len(fits) == 4 and all(r.options["baseline"] for r in train)
    assert all(r.options["refine"] == 100 for r in train), "the network is also scored after 100 refinement steps"
    assert {r.config.category: r.options["fit"]["num_cuboids"] for r in fits} == runner.COURSE_NUM_CUBOIDS
    _, without = _runs(table12, "--without-fitting")
    assert [r.task for r in without] == ["train"] * 4, "--without-fitting leaves out the per-shape fits"


def test_every_full_run_is_estimated_to_finish_within_45_minutes():
    for module in SCRIPTS:
        _, runs = _runs(module)
        assert runner.estimate_makespan(runs, 2) < 45 * 60, module.EXPERIMENT.name


# ----------------------------------------------------------------------------------------------
# End to end
# ----------------------------------------------------------------------------------------------


def _tiny_experiment() -> command_line.Experiment:
    """Two variants x one seed of a tiny network (the runner's own end-to-end check)."""

    def build(scale, args):
        return [runner.Run(f"lambda{lam:g}", {"lambda_1": lam, "seed": 0},
                           scale.config("chair", loss={"lambda_compact": lam}), options={"sigma_n": 0.01})
                for lam in (0.0, 0.2)]

    def report(records, scale, args):
        summary = runner.summarize(runner.result_rows(records), ("lambda_1",), ("cd", "cd_clean", "miou", "n_ac"))
        return summary, runner.text_table(["lambda_1", "CD"], [[str(r["lambda_1"]), runner.mean_sd(r, "cd", 1000)]
                                                                for r in summary])

    return command_line.Experiment("tiny", "a tiny experiment", "two variants", {"source": "none"}, 3, 1, build, report)


def test_runner_end_to_end_writes_results_with_provenance(tmp_path, capsys):
    code = command_line.main(_tiny_experiment(), ["--quick", "--steps", "3", "--jobs", "1", "--out", str(tmp_path / "res"),
                                            "--runs-dir", str(tmp_path / "runs")])
    assert code == 0
    out = capsys.readouterr().out
    assert "QUICK RUN" in out and "wrote" in out
    data = json.loads((tmp_path / "res" / "tiny_quick.json").read_text())
    for field in ("command", "git_commit", "machine", "started", "wall_seconds", "settings", "course_scale", "paper",
                  "summary", "table", "runs"):
        assert field in data, field
    assert data["command"].startswith("python experiments/tiny.py --quick --steps 3")
    assert data["machine"]["cpus"] == os.cpu_count() and data["machine"]["torch"] == torch.__version__
    assert data["machine"]["jobs"] == 1 and data["wall_seconds"] > 0
    assert data["settings"]["steps"] == 3 and data["failed"] == []
    assert [r["key"]["lambda_1"] for r in data["runs"]] == [0.0, 0.2]
    for record in data["runs"]:
        config = TrainConfig.from_dict(record["config"])  # the complete config of every run
        assert config.loss_config.lambda_compact == record["key"]["lambda_1"] and config.max_steps == 3
        assert record["status"] == "ok" and record["training"]["steps"] == 3
        assert Path(record["checkpoint"]).is_file()
        metrics = record["results"][0]["metrics"]
        assert all(math.isfinite(metrics[k]) for k in ("cd", "nc", "cd_clean", "nc_clean", "n_ac"))
        assert 0 <= metrics["miou"] <= 1
    with open(tmp_path / "res" / "tiny_quick.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["lambda_1"]) for r in rows] == [0.0, 0.2] and all(float(r["cd_mean"]) > 0 for r in rows)

    # the trained tiny network doubles as a "released checkpoint" for Tables 1-2 --checkpoints
    released = tmp_path / "released"
    released.mkdir()
    shutil.copy(data["runs"][0]["checkpoint"], released / "chair.pt")
    _, runs = _runs(table12, "--quick", "--categories", "chair", "--checkpoints", str(released))
    assert [r.task for r in runs] == ["score", "fit"] and runs[0].config.n_shapes == 12
    record = runner.execute(runs[0], tmp_path / "score")
    assert record["status"] == "ok", record.get("error")
    assert [r["method"] for r in record["results"]] == ["network", "network + refinement", "k-means boxes"]
    refined = record["results"][1]
    assert refined["scores"]["refine_steps"] == 5 and 0 <= refined["scores"]["segmentation_kept"] <= 1
    assert refined["metrics"]["n_ac"] <= record["results"][0]["metrics"]["n_ac"], "refinement adds no cuboid"
    boxes = record["results"][2]["metrics"]["boxes"]
    assert boxes == max(1, round(record["results"][0]["metrics"]["n_ac"]))
    # --resume reads the score back while the checkpoint is the same file, and scores a replaced one anew
    assert runner.finished_record(runs[0], tmp_path / "score") is not None
    state = torch.load(released / "chair.pt", weights_only=True)
    state["step"] = state.get("step", 0) + 1
    torch.save(state, released / "chair.pt")
    _, replaced = _runs(table12, "--quick", "--categories", "chair", "--checkpoints", str(released))
    assert runner.finished_record(replaced[0], tmp_path / "score") is None


def test_resume_reads_back_the_finished_runs_and_does_only_the_rest(tmp_path, capsys):
    args = ["--quick", "--steps", "2", "--jobs", "1", "--out", str(tmp_path / "res"), "--runs-dir", str(tmp_path / "runs")]
    assert command_line.main(_tiny_experiment(), args) == 0
    (folder,) = (tmp_path / "runs" / "tiny").iterdir()
    first = json.loads((tmp_path / "res" / "tiny_quick.json").read_text())
    (folder / "lambda0.2" / runner.RECORD_FILE).unlink()  # as if the second run had been interrupted
    capsys.readouterr()
    assert command_line.main(_tiny_experiment(), args + ["--resume"]) == 0
    out = capsys.readouterr().out
    assert f"resuming {folder}: 1 of 2 runs already finished" in out
    second = json.loads((tmp_path / "res" / "tiny_quick.json").read_text())
    assert second["settings"]["runs_dir"] == str(folder) and second["settings"]["reused_runs"] == 1
    assert [bool(r.get("reused")) for r in second["runs"]] == [True, False]
    assert second["runs"][0]["results"] == first["runs"][0]["results"], "the finished run is read back as it was"
    changed = args[:2] + ["3"] + args[3:] + ["--resume"]  # another step budget: another configuration, trained anew
    assert command_line.main(_tiny_experiment(), changed) == 0
    third = json.loads((tmp_path / "res" / "tiny_quick.json").read_text())
    assert third["settings"]["reused_runs"] == 0


def test_a_training_key_ignores_fields_added_later_while_they_keep_their_defaults():
    config = runner.Scale(True, 2, 12, (0,)).config("chair")
    run = runner.Run("a", {"seed": 0}, config)
    legacy = {k: v for k, v in config.to_dict().items() if k not in runner.KEY_NEUTRAL_FIELDS}
    legacy["model"] = {k: v for k, v in legacy["model"].items() if k not in runner.KEY_NEUTRAL_MODEL_FIELDS}
    # the key of the same configuration written before those fields existed
    expected = hashlib.sha256(json.dumps([legacy, 0.0], sort_keys=True).encode()).hexdigest()[:16]
    assert runner.training_key(run) == expected
    warm = runner.Run("b", {"seed": 0}, config.replace(temperature_start=5.0, temperature_steps=10))
    assert runner.training_key(warm) != expected
    normals = runner.Run("c", {"seed": 0}, config.replace(model={"input_normals": "differences"}))
    assert runner.training_key(normals) != expected
    assert config.generator_version == 1  # the recipe file has no generator_version: the committed runs' shapes
    newer = runner.Run("d", {"seed": 0}, config.replace(generator_version=2))
    assert runner.training_key(newer) != expected


def test_a_record_written_before_fields_were_added_is_still_a_finished_run(tmp_path):
    config = runner.Scale(True, 2, 12, (0,)).config("chair")
    run = runner.Run("a", {"seed": 0}, config)
    legacy = {k: v for k, v in config.to_dict().items() if k not in runner.KEY_NEUTRAL_FIELDS}
    legacy["model"] = {k: v for k, v in legacy["model"].items() if k not in runner.KEY_NEUTRAL_MODEL_FIELDS}
    record = {"status": "ok", "name": "a", "task": run.task, "config": legacy, "options": {}}
    (tmp_path / runner.RECORD_FILE).write_text(json.dumps(record))
    assert runner.finished_record(run, tmp_path) == record
    warm = runner.Run("a", {"seed": 0}, config.replace(temperature_start=5.0, temperature_steps=10))
    assert runner.finished_record(warm, tmp_path) is None, "a field away from its default is another configuration"


def test_runs_that_share_a_training_train_once_within_an_invocation_and_across_scripts(tmp_path):
    scale = runner.Scale(True, 2, 12, (0,))
    config = scale.config("chair")
    runs = [runner.Run("a", {"seed": 0}, config), runner.Run("b", {"seed": 0}, config, options={"baseline": True}),
            runner.Run("noisy", {"seed": 0}, config, options={"sigma_n": 0.01})]
    assert runner.training_key(runs[0]) == runner.training_key(runs[1]) != runner.training_key(runs[2])
    records = runner.run_all(runs, tmp_path / "first", jobs=1, report=lambda line: None,
                             trained_dir=tmp_path / "trained")
    assert [r["status"] for r in records] == ["ok"] * 3
    assert sorted(p.name for p in (tmp_path / "trained").iterdir()) == sorted(
        {runner.training_key(r) for r in runs})  # two trainings for three runs
    assert records[0]["checkpoint"] == records[1]["checkpoint"]
    assert not records[0]["training"].get("reused") and records[1]["training"]["reused"]
    assert [r["method"] for r in records[1]["results"]] == ["network", "k-means boxes"]  # scored its own way
    assert records[0]["results"][0]["metrics"] == records[1]["results"][0]["metrics"]
    # another script (another runs folder) with the same store reads both trainings back
    again = runner.run_all(runs[:1] + runs[2:], tmp_path / "second", jobs=1, report=lambda line: None,
                           trained_dir=tmp_path / "trained")
    assert all(r["training"]["reused"] for r in again)
    assert again[0]["results"] == records[0]["results"]


def test_second_stages_that_start_from_the_same_first_stage_share_its_training(tmp_path):
    run = _runs(table5, "--recipe", "15min", "--quick")[1][0]
    other = replace(run, name="other", finetune=run.finetune.replace(lr=5e-4))
    first_key = runner.training_key(replace(run, finetune=None))
    assert len({first_key, runner.training_key(run), runner.training_key(other)}) == 3
    store = tmp_path / "trained"
    records = runner.run_all([run, other], tmp_path / "runs", jobs=1, report=lambda line: None, trained_dir=store)
    assert [r["status"] for r in records] == ["ok", "ok"]
    assert [r["training"]["first_stage_reused"] for r in records] == [False, True]
    assert (store / first_key / "best.pt").is_file()
    for r in (run, other):  # a second stage's folder holds the second stage alone
        assert sorted(p.name for p in (store / runner.training_key(r)).iterdir()
                      if not p.name.startswith(".")) == [runner.FINETUNE_DIR, runner.TRAINING_FILE]
    assert records[0]["training"]["steps"] == records[1]["training"]["steps"] == 2
    assert records[0]["results"] != records[1]["results"]  # two second stages, two networks
    # a training folder begun before first stages were shared keeps its own first stage
    legacy = tmp_path / "legacy"
    runner._train(run, legacy)
    (legacy / runner.TRAINING_FILE).unlink()
    shutil.rmtree(legacy / runner.FINETUNE_DIR)
    summary = runner._train(run, legacy, tmp_path / "empty_store")
    assert "first_stage_reused" not in summary and not (tmp_path / "empty_store").exists()
    assert (legacy / runner.FINETUNE_DIR / "best.pt").is_file()


def test_a_failing_run_is_recorded_and_the_others_go_on(tmp_path):
    scale = runner.Scale(True, 2, 12, (0,))
    good = runner.Run("good", {"seed": 0}, scale.config("chair"))
    bad = runner.Run("bad", {"seed": 1}, scale.config("chair"), task="score", options={"checkpoint": str(tmp_path / "no.pt")})
    lines = []
    records = runner.run_all([bad, good], tmp_path, jobs=1, report=lines.append)
    assert [r["status"] for r in records] == ["failed", "ok"]
    assert "no.pt" in records[0]["error"] and any("FAILED" in line for line in lines)


def test_fig11_quick_writes_the_figure(tmp_path, monkeypatch):
    import cuboidlib.applications as applications

    drawn = []  # the figure places the cuboids as the training losses did (the runs' centroid centres)

    def spy(*args, **kwargs):
        drawn.append(kwargs.get("centers_from_allocation"))
        return real(*args, **kwargs)

    real = applications.abstract_shapes
    monkeypatch.setattr(applications, "abstract_shapes", spy)
    code = command_line.main(fig11.EXPERIMENT, ["--quick", "--jobs", "1", "--out", str(tmp_path), "--runs-dir",
                                          str(tmp_path / "runs")])
    assert code == 0
    assert drawn == [True, True, True]
    data = json.loads((tmp_path / "fig11_point_density_quick.json").read_text())
    assert [r["key"]["points"] for r in data["runs"]] == [32, 128, 512]
    assert all(r["results"][0]["metrics"]["cd_reference"] > 0 for r in data["runs"])
    png = tmp_path / "fig11_point_density_quick.png"
    assert data["files"] == [str(png)] and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_table5_quick_runs_in_worker_processes(tmp_path):
    """The real command line, two jobs in separate processes (the only subprocess of this file)."""
    result = subprocess.run(
        [sys.executable, str(EXPERIMENTS / "table5_compactness.py"), "--quick", "--jobs", "2", "--out", str(tmp_path),
         "--runs-dir", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    data = json.loads((tmp_path / "table5_compactness_quick.json").read_text())
    assert sorted(r["key"]["lambda_1"] for r in data["runs"]) == [0.0, 0.05, 0.1, 0.2]
    assert data["machine"]["jobs"] == 2 and all(r["status"] == "ok" for r in data["runs"])
    assert "Table 5" in result.stdout and "N_AC (paper)" in result.stdout


@pytest.mark.parametrize(
    "module, argv, match",
    [
        (table5, ["--jobs", "0"], "argument --jobs: expected a positive integer, got '0'"),
        (table5, ["--steps", "many"], "argument --steps: expected a positive integer"),
        (table3, ["--categories", "chair,sofa"], "argument --categories: expected a comma-separated list"),
        (table6, ["--shapes", "10"], "--shapes 10 leaves 7 training shapes, fewer than the batch size 8"),
        (table12, ["--checkpoints", "/nonexistent"], "/nonexistent/airplane.pt: no such checkpoint"),
        (table12, ["--checkpoints", "/nonexistent", "--seeds", "2"], "takes no --seeds"),
        (fig11, ["--quick", "--shape", "5"], "--shape 5 is out of range: the test split has 2 shapes"),
        (table3, ["--lambda-compact", "-1"], "--lambda-compact must be a non-negative number"),
        (table3, ["--variants", "P2C-Seg,Seg"], "argument --variants: expected a comma-separated list"),
    ],
)
def test_bad_arguments_give_one_line_errors(module, argv, match, capsys):
    with pytest.raises(SystemExit) as exc:
        command_line.main(module.EXPERIMENT, argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and match in err, err


def test_every_script_has_help_naming_its_table():
    for module in SCRIPTS:
        text = module.EXPERIMENT.parser().format_help()
        assert "--quick" in text and "--jobs" in text and f"experiments/results/{module.EXPERIMENT.name}.json" in text
        assert module.__doc__.splitlines()[0] in text


# ----------------------------------------------------------------------------------------------
# The training curves of the committed networks
# ----------------------------------------------------------------------------------------------


def test_training_curves_are_drawn_from_the_cards(tmp_path, capsys):
    import training_curves

    from cuboidlib.release import curve_marks, read_card, training_curve

    out = tmp_path / "curves.png"
    assert training_curves.main(["--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out.splitlines()
    for category in training_curves.CATEGORIES:
        (line,) = [row for row in printed if row.startswith(category)]
        curve, seconds, starts = training_curve(read_card(ROOT / "data_samples" / "checkpoints" / f"{category}.pt"))
        assert [e["seconds"] for e in curve] == sorted(e["seconds"] for e in curve), "stages one after the other"
        assert seconds <= 60 * 60 and len(starts) == 1, "two stages, at most 60 minutes together"
        marks = curve_marks(curve, seconds)
        assert marks, f"{category}: the card reaches no 15-minute mark"
        for minutes, entry in marks.items():
            assert f"{minutes} min: mIoU {100 * entry['miou']:.1f} %" in line


def test_airplane_engines_moves_the_engine_points_of_mixed_slots_to_free_ones():
    # one shape, 6 points, 3 slots: slot 0 holds two wing points and two engine points, slot 1 one engine
    # point alone, slot 2 is unused
    points = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, -1, 0], [0, -1, 2], [5, 5, 5], [6, 6, 6]])
    parts = torch.tensor([1, 1, 3, 3, 3, 0])
    labels = torch.tensor([[0, 0, 0, 0, 1, 1]])
    cuboids = Cuboids(torch.zeros(1, 3, 3), torch.tensor([[[1.0, 0, 0, 0]] * 3]), torch.ones(1, 3, 3),
                      torch.tensor([[True, True, False]]))
    start, moved = airplane_engines.split_start(AbstractionBatch(cuboids, labels), points, parts, engine=3,
                                                min_points=2)
    assert moved == 2 and start.labels.tolist() == [[0, 0, 2, 2, 1, 1]]
    assert start.cuboids.exists.tolist() == [[True, True, True]]
    torch.testing.assert_close(start.cuboids.centers[0, 2], torch.tensor([0.0, -1, 1]))
    torch.testing.assert_close(start.cuboids.half_sizes[0, 2], torch.tensor([1e-3, 1e-3, 1.0]))
    assert labels.tolist() == [[0, 0, 0, 0, 1, 1]]  # the network's solution is left as it was
    counts = airplane_engines.composition(labels, parts[None], 3, 4)
    assert counts.tolist() == [[0, 2, 0, 2], [1, 0, 0, 1], [0, 0, 0, 0]]


def test_segmentation_errors_box_distances_by_hand():
    # one axis-aligned unit box at the origin and one turned 90 degrees about z, half sizes (2, 1, 1) -> (1, 2, 1)
    turn = [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]
    cuboids = Cuboids(torch.tensor([[[0.0, 0, 0], [10, 0, 0]]]), torch.tensor([[[1.0, 0, 0, 0], turn]]),
                      torch.tensor([[[1.0, 1, 1], [2, 1, 1]]]), torch.tensor([[True, True]]))
    points = torch.tensor([[0.5, 0, 0], [3, 0, 0], [3, 4, 0], [10, 1.5, 0], [12, 0, 0]])
    d = segmentation_errors.box_distances(points, cuboids, 0)
    torch.testing.assert_close(d[:, 0], torch.tensor([0.0, 2, math.hypot(2, 3), math.hypot(9, 0.5), 11]))
    torch.testing.assert_close(d[:, 1], torch.tensor([8.5, 6, math.hypot(6, 2), 0, 1]))


def test_segmentation_errors_moves_foreign_points_of_mixed_slots_to_the_nearest_own_slot():
    # slots: 0 seat (mixed: two seat points, two back points), 1 back at x = 5, 2 back at x = -5, 3 seat (unused)
    names = torch.tensor([1, 0, 0, 1])  # part of every slot: 0 back, 1 seat
    centers = torch.tensor([[[0.0, 0, 0], [5, 0, 0], [-5, 0, 0], [0, 9, 0]]])
    cuboids = Cuboids(centers, torch.tensor([[[1.0, 0, 0, 0]] * 4]), torch.full((1, 4, 3), 0.5),
                      torch.tensor([[True, True, True, False]]))
    points = torch.tensor([[0.0, 0, 0], [0.2, 0, 0], [1, 0, 0], [-1, 0, 0], [5, 0, 0], [-5, 0, 0]])
    parts = torch.tensor([1, 1, 0, 0, 0, 0])
    labels = torch.tensor([[0, 0, 0, 0, 1, 2]])
    start, moved = segmentation_errors.purified_start(AbstractionBatch(cuboids, labels), points, parts, names, {0})
    assert moved == 2 and start.labels.tolist() == [[0, 0, 1, 2, 1, 2]]
    assert start.cuboids.exists.tolist() == [[True, True, True, False]]
    assert labels.tolist() == [[0, 0, 0, 0, 1, 2]]  # the network's solution is left as it was
    # a slot that loses all its points does not exist in the start
    start, moved = segmentation_errors.purified_start(
        AbstractionBatch(cuboids, torch.tensor([[1, 1, 0, 0, 1, 2]])), points, parts, names, {0})
    assert moved == 2 and start.cuboids.exists.tolist() == [[False, True, True, False]]
    # with no slot named after the foreign points' part, nothing moves
    start, moved = segmentation_errors.purified_start(AbstractionBatch(cuboids, labels), points, parts,
                                                      torch.tensor([1, 1, 1, 1]), {0})
    assert moved == 0 and start.labels.tolist() == labels.tolist()
