import json
import math

import numpy as np
import pytest
import torch

from cuboidlib import io
from cuboidlib.dataset import PAPER_ROTATIONS_DEG, PointCloudDataset, rotate_about_y
from cuboidlib.shapes import make_collection, make_shape


@pytest.fixture(scope="module")
def collection():
    return make_collection("animal", 4, 300, seed=0, use_cache=False)


def test_items_from_a_collection_batch_into_model_tensors(collection):
    ds = PointCloudDataset(collection, n_points=128, seed=1)
    assert len(ds) == 4
    item = ds[2]
    assert item["points"].shape == (128, 3) and item["points"].dtype == torch.float32
    assert item["normals"].shape == (128, 3) and item["labels"].dtype == torch.int64
    assert int(item["index"]) == 2 and int(item["structure_id"]) == collection.structure_ids[2]
    # the subset is a subset of the shape's points, with their own normals and labels
    full = torch.as_tensor(collection.points[2])
    match = torch.cdist(item["points"], full).argmin(dim=1)
    torch.testing.assert_close(full[match], item["points"])
    torch.testing.assert_close(torch.as_tensor(collection.normals[2])[match], item["normals"])
    torch.testing.assert_close(torch.as_tensor(collection.labels[2])[match], item["labels"])
    torch.testing.assert_close(torch.as_tensor(collection.instances[2])[match], item["instances"])
    assert len(set(match.tolist())) == 128, "sampling without replacement"
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=3)))
    assert batch["points"].shape == (3, 128, 3) and batch["labels"].shape == (3, 128)


def test_subsets_are_repeatable_and_change_with_the_epoch(collection):
    a, b = PointCloudDataset(collection, n_points=64, seed=7), PointCloudDataset(collection, n_points=64, seed=7)
    torch.testing.assert_close(a[1]["points"], b[1]["points"])
    before = a[1]["points"].clone()
    a.set_epoch(1)
    assert not torch.equal(a[1]["points"], before)
    full = PointCloudDataset(collection)
    assert full[0]["points"].shape == (300, 3)


def test_rotation_augmentation_repeats_each_shape_once_per_angle(collection):
    ds = PointCloudDataset(collection, augment=True)
    assert len(ds) == 4 * len(PAPER_ROTATIONS_DEG) and PAPER_ROTATIONS_DEG == (-10, -5, 0, 5, 10)
    base = torch.as_tensor(collection.points[1])
    for k, angle in enumerate(PAPER_ROTATIONS_DEG):
        item = ds[1 * 5 + k]
        assert int(item["index"]) == 1
        # the up coordinate is unchanged; in the horizontal plane points turn by the angle
        torch.testing.assert_close(item["points"][:, 1], base[:, 1])
        a = math.radians(angle)
        expected_x = base[:, 0] * math.cos(a) + base[:, 2] * math.sin(a)
        torch.testing.assert_close(item["points"][:, 0], expected_x, atol=1e-6, rtol=0)
        # normals turn with the points: their dot products with the points' offsets are kept
        torch.testing.assert_close((item["points"] * item["normals"]).sum(1),
                                   (base * torch.as_tensor(collection.normals[1])).sum(1), atol=1e-5, rtol=0)


def test_rotate_about_y_turns_plus_z_towards_plus_x():
    v = torch.tensor([[0.0, 0.0, 1.0], [0.0, 2.0, 0.0]])
    torch.testing.assert_close(rotate_about_y(v, 90.0), torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]]),
                               atol=1e-7, rtol=0)


def test_files_of_every_kind(tmp_path):
    s = make_shape("chair", 0, n_points=400)
    io.write_point_cloud(tmp_path / "a.ply", s.points * 3 + 1, s.normals, s.labels)
    io.write_point_cloud(tmp_path / "b.npy", s.points, s.normals)
    io.write_point_cloud(tmp_path / "c.txt", s.points)  # no normals: estimated
    s.mesh().export(tmp_path / "d.obj")
    ds = PointCloudDataset([tmp_path / n for n in ("a.ply", "b.npy", "c.txt", "d.obj")], n_points=256)
    items = [ds[i] for i in range(4)]
    assert all(it["points"].shape == (256, 3) and it["normals"].shape == (256, 3) for it in items)
    assert "labels" in items[0] and "labels" not in items[1]
    for it in items:  # normalised on load
        lo, hi = it["points"].min(0).values, it["points"].max(0).values
        assert float(torch.linalg.vector_norm(hi - lo)) <= 1.0 + 1e-5
    cloud = ds.cloud(0)
    np.testing.assert_allclose(cloud.points * cloud.scale + cloud.center, s.points * 3 + 1, atol=1e-5)


def test_shapenet_part_and_authors_layouts(tmp_path):
    s = make_shape("table", 0, n_points=300)
    root = tmp_path / "shapenet"
    (root / "train_test_split").mkdir(parents=True)
    (root / "04379243").mkdir()
    (root / "synsetoffset2category.txt").write_text("Table\t04379243\n")
    global_ids = np.where(s.labels == 0, 47, np.where(np.arange(300) % 2 == 0, 48, 49))
    io.write_point_cloud(root / "04379243" / "t1.txt", s.points, s.normals, global_ids)
    (root / "train_test_split" / "shuffled_train_file_list.json").write_text('["shape_data/04379243/t1"]')
    ds = PointCloudDataset.from_shapenet_part(root, "table", "train")
    np.testing.assert_array_equal(ds[0]["labels"].numpy(), s.labels)  # 48 and 49 both -> leg
    authors = tmp_path / "authors"
    (authors / "table").mkdir(parents=True)
    np.save(authors / "table" / "x.npy", np.concatenate([s.points, s.normals], axis=1))
    (authors / "table_test.txt").write_text("x.npy\n")
    ds = PointCloudDataset.from_authors_layout(authors, "table", "test", n_points=100)
    assert len(ds) == 1 and ds[0]["points"].shape == (100, 3) and "labels" not in ds[0]


def test_training_reads_a_shapenet_part_root_and_the_authors_layout(tmp_path):
    from cuboidlib.dataset import data_layout, load_splits
    from cuboidlib.train_config import TrainConfig

    root = tmp_path / "shapenet"
    (root / "train_test_split").mkdir(parents=True)
    (root / "03001627").mkdir()
    (root / "04379243").mkdir()
    (root / "synsetoffset2category.txt").write_text("Chair\t03001627\nTable\t04379243\n")
    lists = {"train": [], "val": [], "test": []}
    for k in range(10):  # chairs spread over the three published splits, and a table that must be left out
        s = make_shape("chair", k, n_points=200)
        io.write_point_cloud(root / "03001627" / f"c{k}.txt", s.points, s.normals, s.labels + 12)  # global ids 12-15
        lists[("train", "train", "train", "train", "train", "train", "val", "val", "test", "test")[k]].append(
            f"shape_data/03001627/c{k}")
    t = make_shape("table", 0, n_points=200)
    io.write_point_cloud(root / "04379243" / "t0.txt", t.points, t.normals, np.full(200, 47))
    lists["train"].append("shape_data/04379243/t0")
    for split, entries in lists.items():
        (root / "train_test_split" / f"shuffled_{split}_file_list.json").write_text(json.dumps(entries))
    assert data_layout(root, "chair") == "shapenet-part" and data_layout(tmp_path, "chair") == "files"
    config = TrainConfig(category="chair", data_dir=str(root), n_points=128)
    splits = load_splits(config)
    assert sum(len(s) for s in splits.values()) == 10, "every chair of the three lists, and no table"
    assert splits["train"].part_names == ("back", "seat", "leg", "arm")
    assert int(splits["test"].labels.max()) <= 3 and splits["test"].points.shape[1:] == (128, 3)

    authors = tmp_path / "authors"
    (authors / "chair").mkdir(parents=True)
    for k in range(6):
        s = make_shape("chair", k, n_points=200)
        np.save(authors / "chair" / f"x{k}.npy", np.concatenate([s.points, s.normals], axis=1))
    np.save(authors / "chair_train.npy", np.array([f"x{k}" for k in range(4)]))
    (authors / "chair_test.txt").write_text("x4.npy\nx5.npy\n")
    assert data_layout(authors, "chair") == "authors"
    splits = load_splits(TrainConfig(category="chair", data_dir=str(authors), n_points=128))
    assert sum(len(s) for s in splits.values()) == 6 and splits["train"].labels is None


def test_bad_inputs(tmp_path, collection):
    with pytest.raises(ValueError, match="n_points=500 is more than the 300 points"):
        PointCloudDataset(collection, n_points=500)
    with pytest.raises(ValueError, match="source is empty"):
        PointCloudDataset([])
    with pytest.raises(TypeError, match="source item 0 must be a file path or a PointCloud"):
        PointCloudDataset([42])
    with pytest.raises(ValueError, match="at least one angle"):
        PointCloudDataset(collection, augment=True, rotations_deg=())
    with pytest.raises(IndexError, match="out of range"):
        PointCloudDataset(collection)[4]
    s = make_shape("chair", 0, n_points=100)
    io.write_point_cloud(tmp_path / "small.ply", s.points, s.normals)
    ds = PointCloudDataset([tmp_path / "small.ply"], n_points=200)
    with pytest.raises(ValueError, match="small.ply: has only 100 points, fewer than"):
        ds[0]
    ds = PointCloudDataset([tmp_path / "missing.ply"])
    with pytest.raises(FileNotFoundError, match="missing.ply: no such file"):
        ds[0]


def test_procedural_shape_sets_keep_the_part_instances_through_splits():
    from cuboidlib.dataset import DataConfig, load_splits

    config = DataConfig(category="table", n_shapes=10, n_points=64, data_seed=2)
    splits = load_splits(config)
    coll = make_collection("table", 10, 64, seed=2, use_cache=False)
    for split in splits.values():
        torch.testing.assert_close(split.instances, torch.as_tensor(coll.instances)[split.indices])
        assert split.to("cpu").instances is not None
