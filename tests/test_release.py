"""Tests of releasing a trained run: the slim checkpoint, its card, the two stages in one command, and the committed
recipes."""

import csv
import json
import time
from pathlib import Path

import pytest
import torch

from cuboidlib.checkpoint import load_checkpoint, load_model
from cuboidlib.cli import main
from cuboidlib.losses import LossConfig
from cuboidlib.train_config import TrainConfig
from tiny_run import TINY_MODEL, assert_same_state, weights

pytestmark = pytest.mark.usefixtures("restore_threads")


def test_cli_release_writes_a_slim_checkpoint_and_its_card(tmp_path, tiny, capsys, monkeypatch):
    from cuboidlib.release import read_card

    config, splits = tiny
    cfg = config.replace(max_steps=4).save_json(tmp_path / "c.json")
    dest = tmp_path / "published" / "chair.pt"
    # the commit is read before the checkpoint is written (replacing a committed one would read as "+dirty")
    monkeypatch.setattr("cuboidlib.release.git_commit", lambda: "written" if dest.exists() else "before")
    argv = ["train", "--config", str(cfg), "--out", str(tmp_path / "run"), "--quiet", "--release", str(dest)]
    before = time.time()
    assert main(argv) == 0
    command_seconds = time.time() - before
    released = load_checkpoint(dest)
    assert "optimizer" not in released and "rng" not in released
    best = load_checkpoint(tmp_path / "run" / "best.pt")
    assert released["step"] == best["step"] and released["config"] == best["config"]
    assert_same_state(released["model"], best["model"])
    card = read_card(dest)
    assert card["command"] == "cuboidlib " + " ".join(argv) and card["git_commit"] == "before"
    assert card["config"] == best["config"]
    assert card["training"]["steps"] == 4 and card["training"]["selected_step"] == best["step"]
    assert card["training"]["selection"] == "lowest validation loss"
    logged = [row for row in csv.DictReader(open(tmp_path / "run" / "log.csv")) if row["split"] == "train"]
    assert card["training"]["seconds"] == round(float(logged[-1]["seconds"]), 1) >= 0  # a tiny run may round to 0.0
    # the whole command, data and scoring included, up to the card
    assert card["training"]["seconds"] + card["test"]["evaluation_seconds"] - 0.2 <= card["command_seconds"]
    assert card["command_seconds"] <= command_seconds + 0.1
    assert card["test"]["n_shapes"] == len(splits["test"])
    validated = [row for row in csv.DictReader(open(tmp_path / "run" / "log.csv")) if row["split"] == "val"]
    curve = card["training"]["validation"]
    assert [e["step"] for e in curve] == [int(r["step"]) for r in validated] and curve
    assert all(0 <= e["miou"] <= 1 and e["n_ac"] >= 0 and e["box_distance"] >= 0 for e in curve)
    assert card["training"]["at_minutes"] == {}, "a run of seconds reaches none of the 15 / 30 / 60 minute marks"
    network, baseline = card["test"]["results"]
    assert network["method"].startswith("network") and baseline["method"].startswith("k-means boxes")
    assert baseline["num_cuboids"] == max(1, round(network["n_ac"]))
    for row in (network, baseline):
        assert row["chamfer"][0]["value"] > 0 and 0 <= row["miou"] <= 1
        assert row["box_distance"] >= 0 and set(row["part_iou"]) == set(splits["test"].part_names)
    assert 0 <= network["reassigned"] <= 1 and baseline["reassigned"] is None
    assert "squared L2" in card["test"]["table"]
    from cuboidlib.release import cards_markdown

    header, _, row = cards_markdown([dest]).splitlines()
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert header.endswith("| N_AC | box distance |") and len(cells) == 9
    assert cells[0] == "`chair.pt`" and cells[-2:] == [f"{network['n_ac']:.2f}", f"{network['box_distance']:.4f}"]
    header, _, row = cards_markdown([dest], short=True).splitlines()
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert header.startswith("| network | M |") and len(cells) == 5
    assert cells[0] == "chair" and cells[2].startswith(f"{1000 * network['chamfer'][0]['value']:.2f} / ")
    assert cells[3] == f"{100 * network['miou']:.1f} / {100 * baseline['miou']:.1f}" and cells[4] == f"{network['n_ac']:.2f}"


def test_card_of_a_two_stage_recipe_holds_both_stages(tmp_path, tiny, capsys):
    from cuboidlib.release import read_card

    config, _ = tiny
    first = config.replace(max_steps=3).save_json(tmp_path / "first.json")
    assert main(["train", "--config", str(first), "--out", str(tmp_path / "stage1"), "--quiet"]) == 0
    second = config.replace(max_steps=2, lr_schedule="cosine", init_from=str(tmp_path / "stage1" / "best.pt"))
    dest = tmp_path / "chair.pt"
    assert main(["train", "--config", str(second.save_json(tmp_path / "second.json")), "--out", str(tmp_path / "stage2"),
                 "--quiet", "--release", str(dest)]) == 0
    card = read_card(dest)
    earlier = card["initialised_from"]
    assert earlier["checkpoint"] == str(tmp_path / "stage1" / "best.pt")
    assert earlier["config"]["max_steps"] == 3 and earlier["training"]["steps"] == 3
    assert card["config"]["init_from"] == earlier["checkpoint"] and card["training"]["steps"] == 2


def test_finetune_runs_both_stages_in_one_command_as_two_commands_would(tmp_path, tiny):
    from cuboidlib.release import read_card
    from cuboidlib.train import FINETUNE_DIR

    config, _ = tiny
    first = config.replace(max_steps=3).save_json(tmp_path / "first.json")
    second = config.replace(max_steps=2, lr_schedule="cosine", model={"affinity_temperature": 5},
                            init_from="elsewhere/best.pt").save_json(tmp_path / "second.json")
    # two commands: the second stage told where the first one's weights are
    assert main(["train", "--config", str(first), "--out", str(tmp_path / "a"), "--quiet"]) == 0
    assert main(["train", "--config", str(second), "--out", str(tmp_path / "b"), "--quiet",
                 "--set", f"init_from={json.dumps(str(tmp_path / 'a' / 'best.pt'))}"]) == 0
    # one command
    dest = tmp_path / "chair.pt"
    assert main(["train", "--config", str(first), "--finetune", str(second), "--out", str(tmp_path / "one"), "--quiet",
                 "--release", str(dest)]) == 0
    assert_same_state(weights(tmp_path / "a" / "best.pt"), weights(tmp_path / "one" / "best.pt"))
    assert_same_state(weights(tmp_path / "b" / "best.pt"), weights(tmp_path / "one" / FINETUNE_DIR / "best.pt"))
    card = read_card(dest)
    assert card["initialised_from"]["checkpoint"] == str(tmp_path / "one" / "best.pt")
    assert card["initialised_from"]["training"]["steps"] == 3 and card["training"]["steps"] == 2
    assert card["config"]["model"]["affinity_temperature"] == 5
    assert card["machine"]["processes"] == 1 and card["command"].startswith("cuboidlib train --config")
    # --resume after the second stage has begun continues it and leaves the first alone
    first_log = (tmp_path / "one" / "log.csv").read_text()
    assert main(["train", "--config", str(first), "--finetune", str(second), "--out", str(tmp_path / "one"), "--quiet",
                 "--resume"]) == 0
    assert (tmp_path / "one" / "log.csv").read_text() == first_log


def test_finetune_trains_on_the_first_stages_shapes(tmp_path, tiny, capsys):
    config, _ = tiny
    first = config.replace(max_steps=1).save_json(tmp_path / "first.json")
    # data and device flags apply to both stages; data fields the second file leaves out are the first stage's
    partial = tmp_path / "partial.json"
    second = {"max_steps": 1, "lr": 1e-3, "batch_size": 4, "model": config.model, "loss": config.loss}
    partial.write_text(json.dumps(second))
    out = tmp_path / "run"
    assert main(["train", "--config", str(first), "--finetune", str(partial), "--out", str(out), "--quiet",
                 "--data-seed", "3", "--threads", "1"]) == 0
    stages = [TrainConfig.load_json(out / "config.json"), TrainConfig.load_json(out / "finetune" / "config.json")]
    for stage in stages:
        assert stage.data_seed == 3 and stage.num_threads == 1 and stage.n_shapes == config.n_shapes
    assert stages[1].n_points == config.n_points != TrainConfig().n_points and stages[1].lr == 1e-3
    # a second file that selects other shapes is refused before anything is trained
    other = config.replace(n_points=config.n_points + 8).save_json(tmp_path / "other.json")
    assert main(["train", "--config", str(first), "--finetune", str(other), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "must train on the first stage's shapes" in err
    assert f"n_points {config.n_points} / {config.n_points + 8}" in err
    assert not (tmp_path / "x").exists()
    # --set changes the first stage only, so it cannot make the two stages' shapes differ unnoticed
    assert main(["train", "--config", str(first), "--finetune", str(first), "--out", str(tmp_path / "x"),
                 "--set", "n_shapes=12"]) == 2
    assert "n_shapes 12 / " in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_release_of_a_centroid_network_fits_its_translation_head(tmp_path, tiny):
    from cuboidlib.release import read_card, translation_head_error

    config, splits = tiny
    config = config.replace(loss=LossConfig.authors_code().to_dict(), max_steps=6)
    cfg = config.save_json(tmp_path / "c.json")
    dest = tmp_path / "chair.pt"
    assert main(["train", "--config", str(cfg), "--out", str(tmp_path / "run"), "--quiet", "--release", str(dest)]) == 0
    card = read_card(dest)
    fit = card["translation_head"]
    assert fit["rms_error_validation_after"] < fit["rms_error_validation_before"]
    released, _ = load_model(dest)
    error = translation_head_error(released, splits["val"].points)
    assert error == pytest.approx(fit["rms_error_validation_after"], abs=1e-5), "the released head is the fitted one"
    best = load_checkpoint(tmp_path / "run" / "best.pt")["model"]
    changed = [k for k, v in released.state_dict().items() if not torch.equal(v, best[k])]
    assert sorted(changed) == ["abstraction.D_cp.translation.bias", "abstraction.D_cp.translation.weight"]


def test_a_network_that_reads_normals_trains_releases_and_abstracts_a_file(tmp_path, tiny):
    # ModelConfig.input_normals end to end: training, validation, the translation-head fit and the
    # test evaluation of the release, then the one pipeline on a mesh file (normals from the file).
    import cuboidlib
    from cuboidlib.release import publish_run, read_card, translation_head_error

    config, splits = tiny
    model = {**TINY_MODEL.to_dict(), "input_normals": "differences"}
    config = config.replace(model=model, loss=LossConfig.authors_code().to_dict(), max_steps=6)
    cfg = config.save_json(tmp_path / "c.json")
    assert main(["train", "--config", str(cfg), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    # a tiny network after 6 steps may switch every cuboid off; the release needs existing ones
    best = tmp_path / "run" / "best.pt"
    state = torch.load(best, weights_only=True)
    bias = [k for k in state["model"] if k.startswith("abstraction.D_cp.existence.") and k.endswith(".bias")][-1]
    state["model"][bias].fill_(5.0)
    torch.save(state, best)
    dest = tmp_path / "chair.pt"
    publish_run(tmp_path / "run", dest, command="cuboidlib train (test)")
    card = read_card(dest)
    assert card["config"]["model"]["input_normals"] == "differences"
    released, _ = load_model(dest)
    assert released.embedding.edge_convs[0].conv1.in_features == 9
    error = translation_head_error(released, splits["val"].points, splits["val"].normals)
    assert error == pytest.approx(card["translation_head"]["rms_error_validation_after"], abs=1e-5)
    with pytest.raises(ValueError, match="reads each point's normal"):
        translation_head_error(released, splits["val"].points)
    mesh = Path(__file__).resolve().parents[1] / "data_samples" / "meshes" / "chair_0.ply"
    for up in ("y", None, "auto"):  # as given, with the orientation check, and in all 24 frames
        result = cuboidlib.abstract(mesh, model=dest, n_points=96, up=up)
        assert result.labels.shape == (96,) and result.numpy()["centers"].shape[1] == 3


def test_cli_release_refuses_a_bad_file_name_before_training(tmp_path, tiny, capsys):
    config, _ = tiny
    cfg = config.replace(max_steps=2).save_json(tmp_path / "c.json")
    assert main(["train", "--config", str(cfg), "--out", str(tmp_path / "run"), "--release", "x.json"]) == 2
    assert "must end in .pt" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
    blocker = tmp_path / "file"
    blocker.write_text("a file where the release folder should be")
    release = str(blocker / "net.pt")
    assert main(["train", "--config", str(cfg), "--out", str(tmp_path / "run"), "--release", release]) == 2
    assert f"--release {release}: cannot write there" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_read_card_rejects_missing_and_foreign_files(tmp_path):
    from cuboidlib.release import read_card

    with pytest.raises(FileNotFoundError, match="no checkpoint card"):
        read_card(tmp_path / "none.pt")
    (tmp_path / "x.json").write_text('{"a": 1}')
    with pytest.raises(ValueError, match="not a cuboidlib checkpoint card"):
        read_card(tmp_path / "x.pt")


def test_course_config_is_the_committed_recipe():
    from cuboidlib.train_config import course_config

    for category in ("airplane", "chair", "table", "animal"):
        config = course_config(category)
        assert config.category == category
        assert config == TrainConfig.load_json(Path(__file__).parents[1] / f"data_samples/checkpoints/configs/{category}.json")
    assert course_config("chair", max_minutes=5, loss={"lambda_compact": 0.5}).loss_config.lambda_compact == 0.5
    with pytest.raises(ValueError, match="no committed recipe for 'lamp'"):
        course_config("lamp")
