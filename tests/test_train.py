import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import cuboidlib.train as train_module
from cuboidlib.checkpoint import CheckpointMismatch, load_checkpoint, save_checkpoint
from cuboidlib.cli import main
from cuboidlib.dataset import load_splits, split_indices
from cuboidlib.losses import LossConfig
from cuboidlib.model import ModelConfig
from cuboidlib.train import Trainer, TrainingDiverged, validation_loss
from cuboidlib.train_config import TrainConfig
from tiny_run import TINY_MODEL, assert_same_state, weights


pytestmark = pytest.mark.usefixtures("restore_threads")


# ------------------------------------------------------------------------------------- config


def test_defaults_are_the_papers_training_settings():
    c = TrainConfig()
    # Sec. 3.4.5: Adam, 1000 epochs, batch size 32, learning rate 6e-4; Sec. 4.1: a 4:1 train/test ratio of which
    # we keep part of the training share for validation; 4096 points per shape as in the authors' data.
    assert (c.lr, c.batch_size, c.epochs, c.n_points) == (6e-4, 32, 1000, 4096)
    assert c.split_fractions[2] == pytest.approx(0.2)
    assert c.model_config == ModelConfig() and c.loss_config == LossConfig()


def test_config_round_trips_through_json(tmp_path):
    c = TrainConfig(category="table", n_shapes=40, model=TINY_MODEL, loss=LossConfig.authors_code(), max_minutes=2.5,
                    split_fractions=[0.6, 0.2, 0.2], data_dir=None)
    back = TrainConfig.load_json(c.save_json(tmp_path / "c.json"))
    assert back == c
    assert json.loads((tmp_path / "c.json").read_text())["model"]["num_cuboids"] == 4


def test_partial_config_file_fills_in_defaults(tmp_path):
    (tmp_path / "c.json").write_text(json.dumps({"lr": 1e-3, "model": {"num_cuboids": 8}}))
    c = TrainConfig.load_json(tmp_path / "c.json")
    assert c.lr == 1e-3 and c.model_config == ModelConfig(num_cuboids=8) and c.batch_size == 32


@pytest.mark.parametrize(
    "change, match",
    [
        ({"lr": -1.0}, "lr must be a positive"),
        ({"split_fractions": (0.9, 0.0, 0.1)}, "split_fractions"),
        ({"split_fractions": (0.5, 0.2, 0.2)}, "summing to 1"),
        ({"batch_size": 0}, "batch_size must be an integer >= 1"),
        ({"category": "lamp"}, "category must be one of"),
        ({"device": "tpu"}, "device must be"),
        ({"model": {"k": 0}}, "ModelConfig.k"),
        ({"loss": {"distance": "hausdorff"}}, "distance must be one of"),
        ({"learning_rate": 1e-3}, "unknown TrainConfig key"),
        ({"lr_schedule": "step"}, "lr_schedule must be one of"),
        ({"lr_final": 1.0}, "lr_final must be a number between 0 and lr"),
        ({"temperature_start": 0.5}, "temperature_start must be a number in"),
        ({"temperature_steps": -1}, "temperature_steps must be an integer >= 0"),
        ({"selection": "best"}, "selection must be one of"),
    ],
)
def test_bad_config_values_are_refused(change, match):
    with pytest.raises(ValueError, match=match):
        TrainConfig.from_dict({**TrainConfig().to_dict(), **change})


def test_config_file_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such config file"):
        TrainConfig.load_json(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{lr: 1}")
    with pytest.raises(ValueError, match="bad.json: not valid JSON"):
        TrainConfig.load_json(tmp_path / "bad.json")


# ---------------------------------------------------------------------------------------- data


def test_split_indices_partition_the_shapes_repeatably():
    s = split_indices(50, (0.7, 0.1, 0.2), seed=5)
    assert [len(s[k]) for k in ("train", "val", "test")] == [35, 5, 10]
    assert torch.equal(torch.cat(list(s.values())).sort().values, torch.arange(50))
    again = split_indices(50, (0.7, 0.1, 0.2), seed=5)
    assert all(torch.equal(s[k], again[k]) for k in s)
    assert not torch.equal(s["test"], split_indices(50, (0.7, 0.1, 0.2), seed=6)["test"])
    with pytest.raises(ValueError, match="too few"):
        split_indices(2, (0.7, 0.1, 0.2), seed=0)


def test_load_splits_gives_disjoint_labelled_point_sets(tiny):
    config, splits = tiny
    assert [len(splits[k]) for k in ("train", "val", "test")] == [14, 2, 4]
    for s in splits.values():
        assert s.points.shape[1:] == (96, 3) and s.normals.shape == s.points.shape
        assert s.labels.shape == s.points.shape[:2] and s.num_parts == 4
    seen = torch.cat([s.indices for s in splits.values()])
    assert len(set(seen.tolist())) == 20


def test_data_dir_of_point_cloud_files(tmp_path, tiny):
    _, splits = tiny
    from cuboidlib.io import write_point_cloud

    for i in range(6):
        write_point_cloud(tmp_path / f"s{i}.ply", splits["train"].points[i].numpy(), splits["train"].normals[i].numpy(),
                          splits["train"].labels[i].numpy())
    config = TrainConfig(data_dir=str(tmp_path), n_points=64, split_fractions=(0.6, 0.2, 0.2))
    loaded = load_splits(config)
    assert [len(loaded[k]) for k in ("train", "val", "test")] == [4, 1, 1]
    assert loaded["train"].points.shape == (4, 64, 3) and loaded["train"].labels is not None
    with pytest.raises(FileNotFoundError, match="no such data folder"):
        load_splits(TrainConfig(data_dir=str(tmp_path / "nope")))


# ----------------------------------------------------------------------------------- training


def test_training_writes_checkpoints_logs_and_best_by_validation(tmp_path, tiny):
    config, splits = tiny
    result = Trainer(config, tmp_path, quiet=True, splits=splits).run()
    assert result.step == 9 and result.stopped == "finished"
    assert {"last.pt", "best.pt", "config.json", "log.csv"} <= {p.name for p in tmp_path.iterdir()}
    assert TrainConfig.load_json(tmp_path / "config.json") == config
    with (tmp_path / "log.csv").open() as f:
        rows = list(csv.DictReader(f))
    train_rows = [r for r in rows if r["split"] == "train"]
    val_rows = [r for r in rows if r["split"] == "val"]
    assert [int(r["step"]) for r in train_rows] == list(range(1, 10))
    assert [int(r["step"]) for r in val_rows] == [4, 8, 9]  # every validate_every steps and at the end
    best = min(val_rows, key=lambda r: float(r["total"]))
    stored = load_checkpoint(tmp_path / "best.pt")
    assert stored["best_step"] == int(best["step"]) == result.best_step
    assert stored["best_val"] == pytest.approx(float(best["total"]), rel=1e-5)
    last = load_checkpoint(tmp_path / "last.pt")
    assert last["step"] == 9 and last["epoch"] == 3  # 14 training shapes // batch 4 = 3 steps per epoch


def test_model_selection_sees_only_the_validation_split(tmp_path, tiny, monkeypatch):
    config, splits = tiny
    seen = []

    def spy(model, shapes, *args, **kwargs):
        seen.append(shapes.indices.clone())
        return validation_loss(model, shapes, *args, **kwargs)

    monkeypatch.setattr(train_module, "validation_loss", spy)
    Trainer(config.replace(max_steps=4), tmp_path, quiet=True, splits=splits).run()
    assert seen and all(torch.equal(s, splits["val"].indices) for s in seen)
    assert not set(splits["val"].indices.tolist()) & set(splits["test"].indices.tolist())


def test_validation_loss_is_a_deterministic_function_of_theweights(tiny):
    config, splits = tiny
    torch.manual_seed(0)
    model = train_module.CuboidAbstractionNet(TINY_MODEL)
    a = validation_loss(model, splits["val"], config.loss_config, 4, seed=1)
    b = validation_loss(model, splits["val"], config.loss_config, 4, seed=1)
    assert a == b and model.training  # the training flag is restored
    assert set(a) == {"total", "reconstruction", "compactness", "existence", "kl", "consistency", "n_existing", "saturated",
                      "affinity_gap"}


def test_resume_gives_bitwise_the_same_weights_as_an_uninterrupted_run(tmp_path, tiny):
    config, splits = tiny
    Trainer(config, tmp_path / "full", quiet=True, splits=splits).run()
    Trainer(config.replace(max_steps=5), tmp_path / "cut", quiet=True, splits=splits).run()
    assert load_checkpoint(tmp_path / "cut" / "last.pt")["step"] == 5  # stopped in the middle of epoch 1
    resumed = Trainer(config, tmp_path / "cut", resume=True, quiet=True, splits=splits)
    assert resumed.step == 5
    resumed.run()
    full, cut = load_checkpoint(tmp_path / "full" / "last.pt"), load_checkpoint(tmp_path / "cut" / "last.pt")
    assert_same_state(full["model"], cut["model"])
    for a, b in zip(full["optimizer"]["state"].values(), cut["optimizer"]["state"].values()):
        assert_same_state(a, b)
    # Same loss terms at every step. The cut run also validated where it stopped (step 5), so its validation
    # rows are those of the full run plus that one.
    def without_seconds(name):  # every column but the wall-clock seconds
        table = list(csv.reader((tmp_path / name / "log.csv").open()))
        drop = table[0].index("seconds")
        return [r[:drop] + r[drop + 1:] for r in table]

    rows = {name: without_seconds(name) for name in ("full", "cut")}
    assert [r for r in rows["full"] if r[2] != "val"] == [r for r in rows["cut"] if r[2] != "val"]
    assert [r for r in rows["cut"] if r[2] == "val" and r[0] != "5"] == [r for r in rows["full"] if r[2] == "val"]


def test_a_run_saved_before_a_config_field_existed_resumes_with_its_default(tmp_path, tiny):
    config, splits = tiny
    Trainer(config.replace(max_steps=3), tmp_path, quiet=True, splits=splits).run()
    state = load_checkpoint(tmp_path / "last.pt")
    old = {k: v for k, v in state["config"].items() if k not in ("temperature_start", "temperature_steps")}
    extra = {k: v for k, v in state.items() if k not in ("config", "model")}
    save_checkpoint(tmp_path / "last.pt", old, state["model"], **extra)
    resumed = Trainer(config, tmp_path, resume=True, quiet=True, splits=splits)
    assert resumed.step == 3 and resumed.run().step == 9
    with pytest.raises(CheckpointMismatch, match="temperature_steps"):
        Trainer(config.replace(temperature_steps=2), tmp_path, resume=True, quiet=True, splits=splits)


def test_a_different_seed_gives_differentweights(tmp_path, tiny):
    config, splits = tiny
    Trainer(config.replace(max_steps=2), tmp_path / "a", quiet=True, splits=splits).run()
    Trainer(config.replace(max_steps=2, seed=4), tmp_path / "b", quiet=True, splits=splits).run()
    a, b = weights(tmp_path / "a" / "last.pt"), weights(tmp_path / "b" / "last.pt")
    assert not torch.equal(a["segmentation.point_proj.weight"], b["segmentation.point_proj.weight"])


def test_resume_refuses_a_different_configuration(tmp_path, tiny):
    config, splits = tiny
    Trainer(config.replace(max_steps=3), tmp_path, quiet=True, splits=splits).run()
    with pytest.raises(CheckpointMismatch, match=r"lr: checkpoint has 0.0006, requested 0.001"):
        Trainer(config.replace(lr=1e-3), tmp_path, resume=True, quiet=True, splits=splits)
    with pytest.raises(CheckpointMismatch, match=r"model config .*num_cuboids: checkpoint has 4, requested 5"):
        Trainer(config.replace(model={"num_cuboids": 5}), tmp_path, resume=True, quiet=True, splits=splits)
    # budget and bookkeeping fields may change
    Trainer(config.replace(max_steps=4, validate_every=2, checkpoint_every=1), tmp_path, resume=True, quiet=True,
            splits=splits)


def test_cosine_schedule_goes_from_lr_to_lr_final_and_resumes_exactly(tmp_path, tiny):
    config, splits = tiny
    config = config.replace(lr=1e-3, lr_schedule="cosine", lr_final=1e-4)
    trainer = Trainer(config, tmp_path / "full", quiet=True, splits=splits)
    rates = [trainer.learning_rate(step) for step in range(trainer.total_steps)]
    assert rates[0] == pytest.approx(1e-3) and rates[-1] == pytest.approx(1e-4)
    assert rates[trainer.total_steps // 2] == pytest.approx(0.5 * (1e-3 + 1e-4), rel=0.15)
    assert all(a >= b for a, b in zip(rates, rates[1:]))
    trainer.run()
    assert trainer.optimizer.param_groups[0]["lr"] == pytest.approx(1e-4)
    with pytest.raises(ValueError, match="resume it with the same epochs / max_steps"):
        Trainer(config.replace(max_steps=4), tmp_path / "full", resume=True, quiet=True, splits=splits)
    assert Trainer(config.replace(lr_schedule="constant"), tmp_path / "c", quiet=True, splits=splits).learning_rate(7) == 1e-3


def test_learning_rate_warm_up_rises_linearly_then_follows_the_schedule(tmp_path, tiny):
    config, splits = tiny
    constant = Trainer(config.replace(lr=1e-3, lr_warmup_steps=4), tmp_path / "c", quiet=True, splits=splits)
    assert [constant.learning_rate(k) for k in range(6)] == pytest.approx([2.5e-4, 5e-4, 7.5e-4, 1e-3, 1e-3, 1e-3])
    cosine = config.replace(lr=1e-3, lr_schedule="cosine", lr_final=1e-4, max_steps=10)
    plain = Trainer(cosine, tmp_path / "p", quiet=True, splits=splits)
    warm = Trainer(cosine.replace(lr_warmup_steps=3), tmp_path / "w", quiet=True, splits=splits)
    assert [warm.learning_rate(k) for k in range(10)] == pytest.approx(
        [plain.learning_rate(k) * min(1, (k + 1) / 3) for k in range(10)])
    assert warm.learning_rate(9) == pytest.approx(1e-4)  # the cosine still ends at lr_final
    with pytest.raises(ValueError, match="lr_warmup_steps must be"):
        config.replace(lr_warmup_steps=-1)


def test_cosine_minutes_schedule_falls_over_the_time_budget_and_cosine_ignores_the_clock(tmp_path, tiny, monkeypatch):
    config, splits = tiny
    seconds = iter(range(10**6))  # a clock that moves one second at every reading
    monkeypatch.setattr(train_module, "time", type("Clock", (), {"monotonic": staticmethod(lambda: next(seconds))}))
    config = config.replace(lr=1e-3, lr_schedule="cosine_minutes", lr_final=1e-4, max_steps=10_000, max_minutes=1.0)
    trainer = Trainer(config, tmp_path / "timed", quiet=True, splits=splits)
    rates, rate = [], trainer.learning_rate
    monkeypatch.setattr(trainer, "learning_rate", lambda step, used=0.0: rates.append(rate(step, used)) or rates[-1])
    result = trainer.run()
    assert result.stopped == "time budget" and 5 < result.step < 60
    assert rates[0] > 0.95e-3 and rates[-1] == pytest.approx(1e-4)  # the whole half cosine within the minute
    assert all(a >= b for a, b in zip(rates, rates[1:]))
    with pytest.raises(ValueError, match="resume it with the same max_minutes"):
        Trainer(config.replace(max_minutes=2.0), tmp_path / "timed", resume=True, quiet=True, splits=splits)
    with pytest.raises(ValueError, match='"cosine_minutes" falls over max_minutes, which is None'):
        config.replace(max_minutes=None)
    steps = Trainer(config.replace(lr_schedule="cosine", max_steps=40), tmp_path / "steps", quiet=True, splits=splits)
    assert [steps.learning_rate(k, used) for k, used in ((0, 0.9), (39, 0.0))] == [1e-3, pytest.approx(1e-4)]


def test_temperature_warm_up_falls_geometrically_and_best_is_chosen_after_it(tmp_path, tiny, monkeypatch):
    config, splits = tiny
    config = config.replace(temperature_start=8.0, temperature_steps=6, model={"affinity_temperature": 2.0})
    trainer = Trainer(config, tmp_path, quiet=True, splits=splits)
    temps = [trainer.affinity_temperature(step) for step in range(9)]
    assert temps[0] == pytest.approx(8.0) and temps[3] == pytest.approx(4.0)  # the geometric mean of 8 and 2
    assert temps[6:] == [2.0, 2.0, 2.0] and all(a > b for a, b in zip(temps[:7], temps[1:7]))
    seen = []  # the temperature every forward pass of the run used
    forward = type(trainer.model.segmentation).forward
    monkeypatch.setattr(type(trainer.model.segmentation), "forward",
                        lambda self, *a: (seen.append(self.temperature), forward(self, *a))[1])
    monkeypatch.setattr("cuboidlib.train.validation_loss", lambda *a, **k: {"total": 1.0, "reconstruction": 1.0})
    monkeypatch.setattr(Trainer, "_validation_scores", lambda self: {})
    result = trainer.run()
    assert seen[:4] == pytest.approx(temps[:4])  # steps 0-3 (validation at step 4 comes after step 3)
    assert seen[-1] == 2.0
    # the validation loss is constant: best.pt follows the warm-up to step 4, then the first validation after it
    assert result.best_step == 8 and load_checkpoint(tmp_path / "best.pt")["best_step"] == 8
    assert Trainer(config.replace(temperature_steps=0), tmp_path / "none", quiet=True,
                   splits=splits).affinity_temperature(0) == 2.0


def test_selection_last_keeps_the_last_weights_even_when_the_loss_rises(tmp_path, tiny, monkeypatch):
    config, splits = tiny
    losses = iter([1.0, 2.0, 3.0])  # validations at steps 4, 8 and 9: the first has the lowest loss
    monkeypatch.setattr("cuboidlib.train.validation_loss", lambda *a, **k: {"total": next(losses), "reconstruction": 1.0})
    monkeypatch.setattr(Trainer, "_validation_scores", lambda self: {})
    trainer = Trainer(config.replace(selection="last"), tmp_path, quiet=True, splits=splits)
    result = trainer.run()
    best, last = load_checkpoint(tmp_path / "best.pt"), load_checkpoint(tmp_path / "last.pt")
    assert result.best_step == best["best_step"] == 9 and best["best_val"] == 3.0
    for name, value in last["model"].items():
        torch.testing.assert_close(best["model"][name], value, rtol=0, atol=0, msg=name)
    losses = iter([1.0, 2.0, 3.0])  # the default keeps the lowest
    assert Trainer(config, tmp_path / "default", quiet=True, splits=splits).run().best_step == 4


def test_init_from_starts_with_the_weights_of_another_run(tmp_path, tiny):
    config, splits = tiny
    Trainer(config.replace(max_steps=3), tmp_path / "first", quiet=True, splits=splits).run()
    first = weights(tmp_path / "first" / "best.pt")
    second = Trainer(config.replace(init_from=str(tmp_path / "first" / "best.pt")), tmp_path / "second", quiet=True,
                     splits=splits)
    assert_same_state(first, {k: v for k, v in second.model.state_dict().items()})
    with pytest.raises(CheckpointMismatch, match=r"init_from .*num_cuboids: checkpoint has 4, requested 5"):
        Trainer(config.replace(init_from=str(tmp_path / "first" / "best.pt"), model={"num_cuboids": 5}),
                tmp_path / "third", quiet=True, splits=splits)
    with pytest.raises(FileNotFoundError, match="no such checkpoint"):
        Trainer(config.replace(init_from=str(tmp_path / "missing.pt")), tmp_path / "fourth", quiet=True, splits=splits)


def test_init_from_a_coordinates_only_run_may_start_reading_the_normals(tmp_path, tiny):
    config, splits = tiny
    Trainer(config.replace(max_steps=2), tmp_path / "first", quiet=True, splits=splits).run()
    first = weights(tmp_path / "first" / "best.pt")
    second = Trainer(config.replace(init_from=str(tmp_path / "first" / "best.pt"),
                                    model={"input_normals": "differences"}), tmp_path / "second", quiet=True,
                     splits=splits)
    widened = second.model.state_dict()
    key = "embedding.edge_convs.0.conv1.weight"
    torch.testing.assert_close(widened[key][:, [0, 1, 2, 6, 7, 8]], first[key], rtol=0, atol=0)
    assert widened[key][:, 3:6].abs().max() == 0
    assert_same_state({k: v for k, v in first.items() if k != key}, {k: v for k, v in widened.items() if k != key})
    second.run()  # trains with the normals
    Trainer(config.replace(max_steps=2, model={"input_normals": "differences"}), tmp_path / "third", quiet=True,
            splits=splits).run()
    with pytest.raises(CheckpointMismatch, match=r"input_normals: checkpoint has 'differences', requested 'none'"):
        Trainer(config.replace(init_from=str(tmp_path / "third" / "best.pt")), tmp_path / "fourth", quiet=True,
                splits=splits)


def test_snapshots_are_the_weights_of_one_uninterrupted_run_and_a_second_call_reuses_them(tmp_path, tiny, monkeypatch):
    config, splits = tiny
    result, snaps = train_module.train_with_snapshots(config, tmp_path / "s", (3, 6, 9), splits=splits)
    assert sorted(snaps) == [0, 3, 6, 9] and result.step == 9
    fresh = Trainer(config.replace(max_steps=3), tmp_path / "three", quiet=True, splits=splits)
    assert_same_state(snaps[0], fresh.model.state_dict())  # step 0: the initial weights
    fresh.run()
    assert_same_state(snaps[3], weights(tmp_path / "three" / "last.pt"))
    Trainer(config, tmp_path / "full", quiet=True, splits=splits).run()
    assert_same_state(snaps[9], weights(tmp_path / "full" / "last.pt"))
    assert not torch.equal(snaps[3]["segmentation.point_proj.weight"], snaps[9]["segmentation.point_proj.weight"])

    def no_training(self):
        raise AssertionError("a finished run must be read back, not trained again")

    monkeypatch.setattr(Trainer, "run", no_training)
    again, read_back = train_module.train_with_snapshots(config, tmp_path / "s", (3, 6, 9), splits=splits)
    assert again is None
    for step in snaps:
        assert_same_state(snaps[step], read_back[step])


def test_snapshots_continue_an_interrupted_run_and_refuse_another_configuration(tmp_path, tiny):
    config, splits = tiny
    train_module.train_with_snapshots(config, tmp_path / "s", (3, 6), splits=splits)  # as if stopped after 6
    result, snaps = train_module.train_with_snapshots(config, tmp_path / "s", (3, 6, 9), splits=splits)
    assert result.step == 9
    Trainer(config, tmp_path / "full", quiet=True, splits=splits).run()
    assert_same_state(snaps[9], weights(tmp_path / "full" / "last.pt"))
    before = sorted(p.name for p in (tmp_path / "s").iterdir())
    with pytest.raises(FileExistsError, match="holds a run of another configuration"):
        train_module.train_with_snapshots(config.replace(lr=1e-3), tmp_path / "s", (3, 6, 9), splits=splits)
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == before


@pytest.mark.parametrize("stops, change, match", [
    ((), {}, "stops is empty"),
    ((3, 3), {}, "stops must increase"),
    ((0, 3), {}, "every step of stops must be an integer >= 1"),
    ((3,), {"max_minutes": 1.0}, "max_minutes is 1.0"),
    ((3,), {"lr_schedule": "cosine", "lr_final": 1e-5}, "needs the constant schedule"),
])
def test_snapshots_refuse_bad_stops_and_time_budgets(tmp_path, tiny, stops, change, match):
    config, splits = tiny
    with pytest.raises(ValueError, match=match):
        train_module.train_with_snapshots(config.replace(**change), tmp_path, stops, splits=splits)
    assert not any(tmp_path.iterdir())


def test_a_run_folder_is_never_overwritten_by_accident(tmp_path, tiny):
    config, splits = tiny
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        Trainer(config, tmp_path, resume=True, quiet=True, splits=splits)
    Trainer(config.replace(max_steps=1), tmp_path, quiet=True, splits=splits).run()
    with pytest.raises(FileExistsError, match="already holds a run"):
        Trainer(config, tmp_path, quiet=True, splits=splits)


def test_batch_larger_than_the_training_split_is_refused(tmp_path, tiny):
    config, splits = tiny
    with pytest.raises(ValueError, match="fewer than batch_size 32"):
        Trainer(config.replace(batch_size=32), tmp_path, quiet=True, splits=splits)


def test_time_budget_stops_cleanly_with_a_checkpoint(tmp_path, tiny):
    config, splits = tiny
    result = Trainer(config.replace(max_steps=500, max_minutes=1e-6), tmp_path, quiet=True, splits=splits).run()
    assert result.stopped == "time budget" and result.step < 500
    assert load_checkpoint(tmp_path / "last.pt")["step"] == result.step
    assert load_checkpoint(tmp_path / "best.pt")["step"] == result.step  # validated at the stop


def test_time_budget_counts_the_earlier_sessions_of_a_resumed_run(tmp_path, tiny):
    config, splits = tiny
    config = config.replace(max_steps=500, max_minutes=1e-6)
    first = Trainer(config, tmp_path, quiet=True, splits=splits).run()
    weights, log = load_checkpoint(tmp_path / "best.pt")["model"], (tmp_path / "log.csv").read_text()
    again = Trainer(config, tmp_path, resume=True, quiet=True, splits=splits).run()
    assert again.stopped == "time budget" and again.step == first.step  # the budget was used up: no step
    assert (tmp_path / "log.csv").read_text() == log  # nor a second validation of the same weights
    assert_same_state(load_checkpoint(tmp_path / "best.pt")["model"], weights)
    longer = Trainer(config.replace(max_steps=first.step + 3, max_minutes=10.0), tmp_path, resume=True,
                     quiet=True, splits=splits).run()
    assert longer.stopped == "finished" and longer.step == first.step + 3


# ---------------------------------------------------------------------------------- divergence


def test_nan_loss_stops_with_a_clear_error_and_keeps_the_last_good_checkpoint(tmp_path, tiny, monkeypatch):
    config, splits = tiny
    real = train_module.total_loss
    calls = []

    def poisoned(*args, **kwargs):
        terms = real(*args, **kwargs)
        calls.append(1)
        if len(calls) == 5:  # the forward pass of step 5
            terms.reconstruction = terms.reconstruction * float("nan")
            terms.total = terms.total + terms.reconstruction
        return terms

    monkeypatch.setattr(train_module, "total_loss", poisoned)
    trainer = Trainer(config.replace(validate_every=100), tmp_path, quiet=True, splits=splits)
    with pytest.raises(TrainingDiverged, match=r"step 5: non-finite total, reconstruction.*step 3.*is kept") as info:
        trainer.run()
    assert info.value.step == 5 and info.value.bad == ["total", "reconstruction"]
    last = load_checkpoint(tmp_path / "last.pt")
    assert last["step"] == 3
    assert all(torch.isfinite(v).all() for v in last["model"].values() if v.is_floating_point())


def test_huge_learning_rate_diverges_without_writing_a_broken_checkpoint(tmp_path, tiny):
    config, splits = tiny
    trainer = Trainer(config.replace(lr=1e6, checkpoint_every=1, max_steps=20), tmp_path, quiet=True, splits=splits)
    with pytest.raises(TrainingDiverged, match=r"diverged at step (\d+): non-finite network outputs") as info:
        trainer.run()
    step = info.value.step
    assert f"the last checkpoint (step {step - 1}" in str(info.value)
    last = load_checkpoint(tmp_path / "last.pt")
    assert last["step"] == step - 1
    assert all(torch.isfinite(v).all() for v in last["model"].values() if v.is_floating_point())


def test_cli_reports_divergence_with_exit_code_3(tmp_path, tiny, capsys):
    config, _ = tiny
    cfg = config.replace(lr=1e6, max_steps=20, checkpoint_every=50).save_json(tmp_path / "c.json")
    assert main(["train", "--config", str(cfg), "--out", str(tmp_path / "run"), "--quiet"]) == 3
    assert "training diverged at step" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ CLI


def test_cli_merges_defaults_file_flags_and_set(tmp_path, capsys):
    (tmp_path / "c.json").write_text(json.dumps({"lr": 1e-3, "model": {"k": 12}, "n_shapes": 64}))
    code = main(["train", "--config", str(tmp_path / "c.json"), "--out", str(tmp_path / "r"), "--model-size", "small",
                 "--num-cuboids", "8", "--lr", "2e-3", "--set", "loss.lambda_compact=0.2",
                 "--set", "loss.distance=chamfer",
                 "--set", "max_minutes=30", "--print-config"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    # --model-size replaces the model section (the file's k=12 is gone), --num-cuboids then applies
    assert printed["model"] == ModelConfig.small(num_cuboids=8).to_dict()
    assert printed["lr"] == 2e-3 and printed["n_shapes"] == 64 and printed["max_minutes"] == 30
    assert printed["loss"]["lambda_compact"] == 0.2 and printed["loss"]["distance"] == "chamfer"
    assert main(["train", "--out", str(tmp_path / "r"), "--set", "lr"]) == 2
    assert "--set expects KEY=VALUE" in capsys.readouterr().err


def test_cli_train_and_resume(tmp_path, tiny, capsys):
    config, _ = tiny
    cfg = config.replace(max_steps=3).save_json(tmp_path / "c.json")
    out = str(tmp_path / "run")
    assert main(["train", "--config", str(cfg), "--out", out, "--quiet"]) == 0
    assert main(["train", "--out", out, "--resume", "--max-steps", "4", "--quiet"]) == 0
    assert load_checkpoint(Path(out) / "last.pt")["step"] == 4
    assert main(["train", "--out", out, "--resume", "--lr", "0.1", "--quiet"]) == 2
    assert "lr: checkpoint has 0.0006, requested 0.1" in capsys.readouterr().err
    assert main(["train", "--config", str(cfg), "--out", out, "--quiet"]) == 2  # no silent overwrite


def test_train_help_documents_the_options(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = capsys.readouterr().out
    for flag in ("--config", "--out", "--resume", "--max-minutes", "--batch-size", "--lr", "--set", "torchrun"):
        assert flag in text


# ------------------------------------------------------------------------- real processes


def _env():
    env = dict(os.environ)
    env["OMP_NUM_THREADS"] = "1"
    return env


def test_sigkill_mid_run_then_resume_in_a_new_process_matches_an_uninterrupted_run(tmp_path, tiny):
    config, splits = tiny
    steps = 24
    config = config.replace(max_steps=steps, checkpoint_every=2, validate_every=10, epochs=100)
    cfg = config.save_json(tmp_path / "c.json")
    run = tmp_path / "killed"
    cmd = [sys.executable, "-m", "cuboidlib.cli", "train", "--config", str(cfg), "--out", str(run), "--quiet"]
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (run / "last.pt").exists():
            assert proc.poll() is None, proc.communicate()[1].decode()
            assert time.monotonic() < deadline, "no checkpoint appeared"
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    killed_at = load_checkpoint(run / "last.pt")["step"]
    assert 0 < killed_at < steps  # the run was really interrupted
    done = subprocess.run(cmd + ["--resume"], env=_env(), capture_output=True, timeout=300)
    assert done.returncode == 0, done.stderr.decode()
    Trainer(config, tmp_path / "reference", quiet=True, splits=splits).run()
    assert_same_state(weights(tmp_path / "reference" / "last.pt"), weights(run / "last.pt"))


DDP_SCRIPT = """
import sys, torch
from cuboidlib.train import TrainConfig, Trainer
trainer = Trainer(TrainConfig.load_json(sys.argv[1]), sys.argv[2], quiet=True)
result = trainer.run()
torch.save({"params": dict(trainer.model.named_parameters()), "state": trainer.model.state_dict(),
            "rank": trainer.dist.rank, "world": trainer.dist.world_size, "step": result.step},
           f"{sys.argv[2]}/rank{trainer.dist.rank}.pt")
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run_two_ranks(command, attempts: int = 3):
    """Run ``command`` as ranks 0 and 1 of a two-process group (the variables torchrun sets); both must succeed.

    The port is free when chosen but may be taken by another process before rank 0 binds it; only then
    (rank 0 reports the address in use) is the pair started again on another port.
    """
    for attempt in range(attempts):
        port = str(_free_port())
        procs = [
            subprocess.Popen(
                command,
                env={**_env(), "RANK": str(r), "LOCAL_RANK": str(r), "WORLD_SIZE": "2", "LOCAL_WORLD_SIZE": "2",
                     "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": port},
                stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            )
            for r in (0, 1)
        ]
        _, err0 = procs[0].communicate(timeout=300)
        if procs[0].returncode != 0 and b"address already in use" in err0.lower() and attempt + 1 < attempts:
            procs[1].kill()
            procs[1].communicate()
            continue
        _, err1 = procs[1].communicate(timeout=300)
        assert procs[0].returncode == 0, err0.decode()[-3000:]
        assert procs[1].returncode == 0, err1.decode()[-3000:]
        return


@pytest.mark.parametrize("centroids", [False, True], ids=["predicted centres", "centroid centres"])
def test_two_cpu_processes_with_ddp_end_with_identicalweights(tmp_path, tiny, centroids):
    # Two processes started with the variables torchrun sets (RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR/PORT);
    # `torchrun --nproc_per_node=2 -m cuboidlib train ...` does the same through the command line. With centroid
    # centres (the committed recipe) the translation head receives no gradient, which DDP must be told.
    config, _ = tiny
    loss = LossConfig(centers_from_allocation=centroids).to_dict()
    cfg = config.replace(max_steps=4, checkpoint_every=2, loss=loss).save_json(tmp_path / "c.json")
    (tmp_path / "ddp.py").write_text(DDP_SCRIPT)
    out = tmp_path / "run"
    out.mkdir()
    _run_two_ranks([sys.executable, str(tmp_path / "ddp.py"), str(cfg), str(out)])
    r0, r1 = (torch.load(out / f"rank{r}.pt", weights_only=True) for r in (0, 1))
    assert (r0["rank"], r1["rank"], r0["world"], r0["step"]) == (0, 1, 2, 4)
    assert_same_state(r0["params"], r1["params"])
    # Plain BatchNorm under DDP: running statistics are rank 0's at the start of every forward pass, then each rank
    # adds its own batch; checkpoints hold rank 0's.
    assert_same_state(r0["state"], weights(out / "last.pt"))
    last = load_checkpoint(out / "last.pt")
    assert last["world_size"] == 2 and len(last["rng"]["loss"]) == 2
    assert not torch.equal(last["rng"]["loss"][0], last["rng"]["loss"][1])  # each rank samples its own offsets
    with pytest.raises(ValueError, match="written by a run of 2 process"):
        Trainer(TrainConfig.load_json(cfg), out, resume=True, quiet=True)


def test_every_process_leaves_a_run_only_after_rank_0_has_saved(monkeypatch, tmp_path, tiny):
    # Rank 1 ends its loop while rank 0 still validates and saves. Going on then, it could read a best.pt not yet
    # written (a second stage's init_from) or tear the group down under rank 0. So a run ends at a barrier.
    import torch.distributed as dist

    from cuboidlib.runs import Distributed

    calls = []
    with monkeypatch.context() as patch:
        patch.setattr(dist, "is_initialized", lambda: True)
        patch.setattr(dist, "barrier", lambda: calls.append("barrier"))
        patch.setattr(dist, "destroy_process_group", lambda: calls.append("destroy"))
        patch.setenv("WORLD_SIZE", "2")
        group = Distributed()
        group.stop()
        assert calls == []  # a group it did not start is left alone
        group.owns_group = True
        group.wait()
        group.stop()
        assert calls == ["barrier", "destroy"] and not group.owns_group
        calls.clear()
        patch.setenv("WORLD_SIZE", "1")
        Distributed().wait()
        assert calls == []  # one process: no barrier
    config, splits = tiny
    out = tmp_path / "run"
    monkeypatch.setattr(Distributed, "wait", lambda self: calls.append(("wait", (out / "best.pt").is_file(),
                                                                          (out / "last.pt").is_file())))
    Trainer(config.replace(max_steps=2), out, quiet=True, splits=splits).run()
    assert calls == [("wait", True, True)]  # after the last validation and save


def test_both_stages_in_one_torchrun_command_share_the_processes_and_the_card_says_so(tmp_path, tiny):
    # `torchrun --nproc_per_node=2 -m cuboidlib train --config ... --finetune ... --release ...`, by its variables
    from cuboidlib.release import read_card

    config, _ = tiny
    first = config.replace(max_steps=2).save_json(tmp_path / "first.json")
    second = config.replace(max_steps=2, lr_schedule="cosine").save_json(tmp_path / "second.json")
    out, dest = tmp_path / "run", tmp_path / "chair.pt"
    argv = ["train", "--config", str(first), "--finetune", str(second), "--out", str(out), "--quiet",
            "--release", str(dest)]
    _run_two_ranks([sys.executable, "-m", "cuboidlib", *argv])
    assert load_checkpoint(out / "last.pt")["world_size"] == load_checkpoint(out / "finetune" / "last.pt")["world_size"] == 2
    card = read_card(dest)
    assert card["machine"]["processes"] == 2
    assert card["command"].startswith("torchrun --nproc_per_node=2 -m cuboidlib train --config ")
    assert card["initialised_from"]["training"]["steps"] == 2 and card["training"]["steps"] == 2
