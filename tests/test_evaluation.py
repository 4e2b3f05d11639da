import json
import os

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from cuboidlib.abstraction import AbstractionBatch
from cuboidlib.cli import main
from cuboidlib.dataset import ShapeSet, load_splits
from cuboidlib.evaluation import (
    evaluate_baseline,
    evaluate_model,
    format_table,
    label_transfer_split,
    predict_cuboids,
    score_cuboids,
)
from cuboidlib.geometry import Cuboids, sample_cuboid_surfaces
from cuboidlib.io import write_point_cloud
from cuboidlib.metrics import ChamferConvention
from cuboidlib.model import CuboidAbstractionNet, ModelConfig
from cuboidlib.shapes import make_shape
from cuboidlib.train import Trainer
from cuboidlib.train_config import TrainConfig


def load_model_for_test(path):
    from cuboidlib.checkpoint import load_model

    return load_model(path)[0]

TINY = ModelConfig.small(num_cuboids=4, k=8, edge_dims=(8, 8), global_dim=16, latent_dim=8, cuboid_code_dim=8,
                         cuboid_feature_dims=(16, 16), exist_hidden_dim=8, seg_dim=8)


def _batch(centers, quaternions, half_sizes, exists, labels) -> AbstractionBatch:
    return AbstractionBatch(Cuboids(centers, quaternions, half_sizes, exists), labels)


def _two_box_shapes(n_shapes: int = 5, n_points: int = 400, seed: int = 0):
    """Shapes made of two separate axis-aligned boxes (a "seat" below a "back"), points sampled on their
    surfaces, part label = box index. Returns (ShapeSet, the boxes as an AbstractionBatch with a perfect segmentation)."""
    g = torch.Generator().manual_seed(seed)
    centers = torch.tensor([[0.0, -0.2, 0.0], [0.0, 0.25, -0.2]]).repeat(n_shapes, 1, 1)
    centers = centers + 0.02 * torch.randn(n_shapes, 2, 3, generator=g)
    half = torch.tensor([[0.25, 0.05, 0.15], [0.2, 0.15, 0.03]]).repeat(n_shapes, 1, 1)  # distinct principal axes
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(n_shapes, 2, 1)
    s = sample_cuboid_surfaces(centers, quats, half, n_points, generator=g)
    shapes = ShapeSet(s.points, s.normals, s.cuboid_index.clone(), torch.arange(n_shapes), ("seat", "back"), 2,
                      instances=s.cuboid_index.clone())  # each box one part instance
    exists = torch.ones(n_shapes, 2, dtype=torch.bool)
    return shapes, _batch(centers, quats, half, exists, s.cuboid_index.clone())


def test_label_transfer_split_takes_a_seeded_fifth_to_label():
    labelled, scored = label_transfer_split(10, 0.2, seed=1)
    assert len(labelled) == 2 and len(scored) == 8
    assert torch.equal(torch.cat([labelled, scored]).sort().values, torch.arange(10))
    again = label_transfer_split(10, 0.2, seed=1)
    assert torch.equal(labelled, again[0]) and torch.equal(scored, again[1])
    assert len(label_transfer_split(3, 0.2)[0]) == 1  # at least one labelled shape and one scored
    with pytest.raises(ValueError, match="at least 2 shapes"):
        label_transfer_split(1)
    with pytest.raises(ValueError, match=r"must lie in \(0, 1\)"):
        label_transfer_split(10, 1.0)


def test_perfect_cuboids_and_segmentation_score_perfectly():
    shapes, pred = _two_box_shapes(n_shapes=3)
    r = score_cuboids(shapes, pred, conventions=[ChamferConvention(n_samples=2048)])
    assert r["miou"] == 1.0
    # only points within about one sample spacing (~0.02 here) of an edge may find a sample on the adjacent face
    assert r["normal_consistency"] > 0.9
    turned = _batch(pred.cuboids.centers, torch.tensor([0.9239, 0.0, 0.3827, 0.0]).expand_as(pred.cuboids.quaternions),
                               pred.cuboids.half_sizes, pred.cuboids.exists, pred.labels)  # 45 degrees about y
    # side-face normals now meet the points' normals at 45 degrees (|cos| = 0.71); top and bottom still agree
    assert score_cuboids(shapes, turned, conventions=[ChamferConvention(n_samples=2048)])["normal_consistency"] < \
        r["normal_consistency"] - 0.05
    assert r["n_ac"] == 2.0 and r["n_shapes"] == 3
    shifted = _batch(pred.cuboids.centers + torch.tensor([0.1, 0.0, 0.0]), pred.cuboids.quaternions, pred.cuboids.half_sizes,
                                pred.cuboids.exists, pred.labels)
    r_shifted = score_cuboids(shapes, shifted, conventions=[ChamferConvention(n_samples=2048)])
    # a shift by 0.1 along x moves every side face 0.1 away: the squared CD grows by far more than 0.1^2 / 4
    assert r_shifted["chamfer"][0]["value"] > r["chamfer"][0]["value"] + 0.0025
    assert r_shifted["miou"] == 1.0  # the segmentation did not change


def test_label_transfer_scores_correspondence_not_index_values():
    shapes, pred = _two_box_shapes(n_shapes=10)
    labelled, scored = label_transfer_split(10, 0.2, seed=0)
    # The same cuboid index meaning the other part on every shape: labels still transfer perfectly.
    swapped_everywhere = _batch(pred.cuboids.centers, pred.cuboids.quaternions, pred.cuboids.half_sizes, pred.cuboids.exists,
                                           1 - pred.labels)
    fast = [ChamferConvention(n_samples=64)]  # the Chamfer distance is not what this test is about
    assert score_cuboids(shapes, swapped_everywhere, conventions=fast, seed=0)["miou"] == 1.0
    # Indices that mean one part on the labelled shapes and the other on the scored ones: every scored point is
    # wrong, so both labels have IoU 0.
    inconsistent = pred.labels.clone()
    inconsistent[scored] = 1 - inconsistent[scored]
    r = score_cuboids(shapes, _batch(pred.cuboids.centers, pred.cuboids.quaternions, pred.cuboids.half_sizes, pred.cuboids.exists,
                                                inconsistent), conventions=fast, seed=0)
    assert r["miou"] == 0.0
    assert r["label_transfer"]["n_labelled"] == 2 and r["label_transfer"]["n_scored"] == 8


def test_conventions_share_their_surface_samples():
    shapes, pred = _two_box_shapes()
    c = pred.cuboids
    pred = _batch(c.centers + 0.05, c.quaternions, c.half_sizes, c.exists, pred.labels)
    conventions = [ChamferConvention(n_samples=512), ChamferConvention(directions="mean", n_samples=512),
                   ChamferConvention(scale=100.0, n_samples=512), ChamferConvention(norm="l1", n_samples=512)]
    r = score_cuboids(shapes, pred, conventions=conventions, seed=3)
    sum_, mean, scaled, l1 = (c["value"] for c in r["chamfer"])
    assert mean == pytest.approx(sum_ / 2, rel=1e-6)
    assert scaled == pytest.approx(100 * sum_, rel=1e-6)
    assert l1 != sum_
    assert [c["norm"] for c in r["chamfer"]] == ["squared_l2", "squared_l2", "squared_l2", "l1"]
    assert r == score_cuboids(shapes, pred, conventions=conventions, seed=3)  # repeatable


def test_shapes_without_labels_have_no_miou():
    shapes, pred = _two_box_shapes()
    shapes.labels = None
    r = score_cuboids(shapes, pred, conventions=[ChamferConvention(n_samples=64)])
    assert r["miou"] is None and r["label_transfer"] is None


def test_evaluate_model_runs_the_network_and_falls_back_to_one_cuboid():
    shapes, _ = _two_box_shapes(n_shapes=4, n_points=64)
    torch.manual_seed(0)
    model = CuboidAbstractionNet(TINY)
    r = evaluate_model(model, shapes, conventions=[ChamferConvention(n_samples=256)], batch_size=3)
    assert r["method"] == "network" and r["num_cuboids"] == 4 and model.training  # training flag restored
    assert 1 <= r["n_ac"] <= 4 and 0 <= r["miou"] <= 1 and 0 <= r["normal_consistency"] <= 1
    # Batching changes only floating-point rounding (matrix products of other sizes), not the result.
    again = evaluate_model(model, shapes, conventions=[ChamferConvention(n_samples=256)], batch_size=2)
    assert again.keys() == r.keys() and again["label_transfer"] == r["label_transfer"]
    for key in ("normal_consistency", "miou", "n_ac", "box_distance"):
        assert again[key] == pytest.approx(r[key], rel=1e-4, abs=1e-6), key
    assert again["chamfer"][0]["value"] == pytest.approx(r["chamfer"][0]["value"], rel=1e-4)
    with torch.no_grad():
        model.abstraction.D_cp.existence[-1].bias.fill_(-100.0)  # no cuboid exists anywhere
    r = evaluate_model(model, shapes, conventions=[ChamferConvention(n_samples=256)])
    assert r["shapes_without_existing_cuboid"] == 4 and r["n_ac"] == 1.0
    assert "network: 4 of 4 shapes have no cuboid with existence probability > 0.5" in format_table([r])
    # only the fallback cuboid exists: every point allocated most to another one is reassigned
    with torch.no_grad():
        out = model.eval()(shapes.points)
    kept = out.exist_probs.argmax(dim=1, keepdim=True)
    assert r["reassigned"] == pytest.approx(float((out.W.argmax(dim=-1) != kept).double().mean()))
    assert r["reassigned"] > 0
    assert f"network: {100 * r['reassigned']:.1f} % of the points are allocated most to a cuboid" in format_table([r])
    with torch.no_grad():
        model.abstraction.D_cp.existence[-1].bias.fill_(100.0)  # every cuboid exists: nobody is moved
    assert evaluate_model(model, shapes, conventions=[ChamferConvention(n_samples=256)])["reassigned"] == 0.0


def test_networks_trained_with_centroid_centres_are_scored_with_them():
    shapes, _ = _two_box_shapes(n_shapes=3, n_points=64)
    torch.manual_seed(0)
    model = CuboidAbstractionNet(TINY).eval()
    pred, _ = predict_cuboids(model, shapes, centers_from_allocation=True)
    with torch.no_grad():
        W = model(shapes.points).W
    # c_m = sum_n W_nm p_n / (sum_n W_nm + 1), computed independently of the library
    expected = torch.einsum("bnm,bnc->bmc", W, shapes.points) / (W.sum(dim=1)[..., None] + 1)
    torch.testing.assert_close(pred.cuboids.centers, expected)
    assert not torch.allclose(predict_cuboids(model, shapes)[0].cuboids.centers, expected)


def test_baseline_fits_separate_boxes_and_reports_the_same_metrics():
    shapes, pred = _two_box_shapes(n_shapes=4)
    r = evaluate_baseline(shapes, num_boxes=2, conventions=[ChamferConvention(n_samples=1024)])
    perfect = score_cuboids(shapes, pred, conventions=[ChamferConvention(n_samples=1024)])
    assert r["method"] == "k-means boxes (K=2)" and r["n_ac"] == 2.0
    # k-means finds the two boxes, whose principal-axis boxes are close to the true ones
    assert r["normal_consistency"] > perfect["normal_consistency"] - 0.05
    assert r["chamfer"][0]["value"] < 2 * perfect["chamfer"][0]["value"]
    assert set(r) == set(perfect) | {"method", "num_cuboids", "shapes_without_existing_cuboid", "boxes_per_shape"}
    assert r["reassigned"] is None  # k-means boxes have no allocation
    # the perfect segmentation neither cuts nor merges; k-means finds the same two boxes
    for scores in (perfect, r):
        assert scores["concision"] == {name: {"cuboids_per_instance": 1.0, "instances_per_cuboid": 1.0}
                                       for name in ("seat", "back")}, scores["concision"]
    confusion = r["label_transfer"]["confusion"]
    assert confusion["parts"] == list(shapes.part_names)
    scored = shapes.labels[torch.as_tensor(label_transfer_split(len(shapes))[1])]
    sizes = [int((scored == i).sum()) for i in range(len(shapes.part_names))]
    assert all(0 < sum(row) <= size for row, size in zip(confusion["counts"], sizes)), (confusion, sizes)
    with pytest.raises(ValueError, match="num_boxes must be a positive integer"):
        evaluate_baseline(shapes, num_boxes=0)


def test_format_table_states_every_convention():
    shapes, pred = _two_box_shapes()
    conventions = [ChamferConvention(n_samples=256), ChamferConvention(norm="l2", scale=1000.0, n_samples=256)]
    r = {"method": "network", **score_cuboids(shapes, pred, conventions=conventions)}
    text = format_table([r], title="test split")
    lines = text.splitlines()
    assert lines[0] == "test split"
    assert lines[1].split() == ["method", "shapes", "CD", "[1]", "CD", "[2]", "NC", "mIoU", "N_AC", "box", "dist"]
    assert lines[3].split()[:2] == ["network", "5"] and lines[3].split()[-3:] == ["100.0", "2.00", "0.0000"]
    assert "[1] Chamfer distance: squared L2, mean over points per direction, sum of the two directions" in text
    assert "[2] Chamfer distance: L2 (not squared)" in text and "x1000" in text
    assert "transferred from 1 shapes (20 % of the split" in text
    assert "IoU per part (%), network: " in text and "box dist: mean distance of a point" in text
    shapes.labels = None
    r = score_cuboids(shapes, pred, conventions=[ChamferConvention(n_samples=64)])
    assert "mIoU: not computed" in format_table([{"method": "x", **r}])


def test_evaluate_command_scores_the_test_split(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CUBOIDLIB_CACHE", str(tmp_path / "cache"))
    threads = torch.get_num_threads()
    config = TrainConfig(n_shapes=20, n_points=96, batch_size=4, max_steps=2, validate_every=2, num_threads=1,
                         model=TINY)
    try:
        Trainer(config, tmp_path / "run", quiet=True).run()
    finally:
        torch.set_num_threads(threads)
    out = tmp_path / "eval.json"
    code = main(["evaluate", str(tmp_path / "run" / "best.pt"), "--baseline", "--json", str(out), "--samples", "256",
                 "--chamfer-norm", "squared_l2", "--chamfer-norm", "l1", "--device", "cpu", "--merge"])
    assert code == 0
    text = capsys.readouterr().out
    assert "network (step 2)" in text and "k-means boxes" in text and "[2] Chamfer distance: L1" in text
    assert "network (step 2), merged (0.25)" in text
    data = json.loads(out.read_text())
    n_test = len(load_splits(config)["test"])
    assert data["split"] == "test" and [r["n_shapes"] for r in data["results"]] == [n_test] * 3
    network, merged, kmeans = data["results"]
    counts = predict_cuboids(load_model_for_test(tmp_path / "run" / "best.pt"), load_splits(config)["test"])[0]
    assert kmeans["boxes_per_shape"] in (counts.num_existing().tolist(), counts.num_existing().tolist()[0])
    assert network["merge_growth"] is None and merged["merge_growth"] == 0.25 and merged["n_ac"] <= network["n_ac"]
    with pytest.raises(SystemExit) as bad:
        main(["evaluate", str(tmp_path / "run" / "best.pt"), "--merge", "-1"])
    assert bad.value.code == 2 and "argument --merge: expected a number >= 0, got '-1'" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing.pt")]) == 2
    assert "no such checkpoint" in capsys.readouterr().err
    assert os.path.exists(tmp_path / "run" / "last.pt")

    # an external labelled data set: a folder of labelled point-cloud files, scored whole
    external = tmp_path / "external"
    external.mkdir()
    for k in range(5):
        s = make_shape("chair", 100 + k, n_points=150)
        write_point_cloud(external / f"chair_{k}.ply", s.points * 40 + 3, s.normals, s.labels)  # other units
    code = main(["evaluate", str(tmp_path / "run" / "best.pt"), "--data-dir", str(external), "--split", "all",
                 "--samples", "256", "--device", "cpu", "--json", str(tmp_path / "ext.json")])
    assert code == 0, capsys.readouterr().err
    assert str(external) in capsys.readouterr().out
    ext = json.loads((tmp_path / "ext.json").read_text())
    assert ext["split"] == "all" and ext["results"][0]["n_shapes"] == 5 and 0 <= ext["results"][0]["miou"] <= 1
    assert main(["evaluate", str(tmp_path / "run" / "best.pt"), "--data-dir", str(tmp_path / "none")]) == 2
    assert "no such data folder" in capsys.readouterr().err


@settings(max_examples=15, deadline=None)
@given(counts=st.lists(st.integers(1, 6), min_size=2, max_size=5))
def test_kmeans_boxes_per_shape_are_the_counts_given_property(counts):
    shapes, _ = _two_box_shapes(n_shapes=len(counts), n_points=96)
    r = evaluate_baseline(shapes, counts, conventions=[ChamferConvention(n_samples=64)])
    same = len(set(counts)) == 1
    assert r["boxes_per_shape"] == (counts[0] if same else counts) and r["num_cuboids"] == max(counts)
    assert r["n_ac"] <= sum(counts) / len(counts) + 1e-9  # a box exists where its cluster has points
    assert r["method"] == (f"k-means boxes (K={counts[0]})" if same else
                           f"k-means boxes (K per shape, mean {sum(counts) / len(counts):.2f})")
    with pytest.raises(ValueError, match="for 2 shapes; give one per shape"):
        evaluate_baseline(shapes.subset(torch.arange(2)), [1, 2, 3])


@pytest.mark.parametrize("category", ["chair", "airplane"])
def test_evaluate_on_a_labelled_folder_names_the_parts_and_scores_every_shape(tmp_path, capsys, category):
    from cuboidlib.applications import load_trained_model
    from cuboidlib.dataset import DataConfig, load_shapes, split_indices
    from cuboidlib.shapes import PART_NAMES

    folder = tmp_path / "labelled"
    folder.mkdir()
    n = 12
    for k in range(n):
        s = make_shape(category, 200 + k, n_points=1100)
        write_point_cloud(folder / f"{category}_{k}.ply", s.points * 3 - 1, s.normals, s.labels)
    base = ["evaluate", category, "--data-dir", str(folder), "--samples", "128", "--device", "cpu"]
    assert main([*base, "--baseline", "--json", str(tmp_path / "all.json")]) == 0
    out = capsys.readouterr().out
    assert f"{category}: {category}, data folder {folder}, every shape ({n} shapes" in out.splitlines()[0]
    assert "part labels transferred from 2 shapes" in out and f"to the other {n - 2}" in out
    names = PART_NAMES[category]
    assert "IoU per part (%), network" in out and all(f"{name} " in out for name in names) and "part 0" not in out
    data = json.loads((tmp_path / "all.json").read_text())
    network, kmeans = data["results"]
    assert data["split"] == "all" and network["n_shapes"] == kmeans["n_shapes"] == n
    assert list(network["part_iou"]) == list(names)
    model = load_trained_model(category)[0]
    shapes = load_shapes(DataConfig(category=category, data_dir=str(folder), n_points=1024))
    per_shape = predict_cuboids(model, shapes, centers_from_allocation=True)[0].num_existing().tolist()
    assert kmeans["boxes_per_shape"] in (per_shape, per_shape[0])  # the network's own count, shape by shape
    assert main([*base, "--split", "test"]) == 0
    n_test = len(split_indices(n, DataConfig().split_fractions, DataConfig().split_seed)["test"])
    assert f"test split ({n_test} of {n} shapes; --split all scores every one" in capsys.readouterr().out
    assert main([*base, "--part-names", "a,b"]) == 2
    assert "--part-names: the part labels go up to" in capsys.readouterr().err
    assert main([*base, "--part-names", ",".join(f"p{i}" for i in range(len(names)))]) == 0
    assert "p0 " in capsys.readouterr().out
