"""The generator version in configurations: a config without ``generator_version`` means version 1 (every config
written before the field, the pinned recipes' and the version-1 networks' among them); a new config means the
newest; the version reaches the shapes that training and evaluation read."""

import json
from pathlib import Path

import pytest

from cuboidlib.dataset import UNVERSIONED_GENERATOR, DataConfig, load_shapes
from cuboidlib.shapes import GENERATOR_VERSION, make_collection
from cuboidlib.train_config import TrainConfig, course_config

ROOT = Path(__file__).resolve().parents[1]

#: The generator each committed network was trained on (experiments/README.md, "Networks trained on version 2").
SHIPPED = {"chair": 1, "table": 1, "airplane": 2, "animal": 1}


def test_a_config_without_the_field_means_version_1_and_a_new_config_the_newest():
    assert UNVERSIONED_GENERATOR == 1 and GENERATOR_VERSION == 3
    assert DataConfig.from_dict({}).generator_version == 1
    assert TrainConfig.from_dict({"category": "animal"}).generator_version == 1
    assert TrainConfig().generator_version == DataConfig().generator_version == 3
    assert TrainConfig.from_dict(TrainConfig().to_dict()).generator_version == 3
    assert TrainConfig().replace(lr=1e-3).generator_version == 3
    assert TrainConfig.from_dict({"generator_version": 1}).replace(lr=1e-3).generator_version == 1


@pytest.mark.parametrize("bad", [0, 4, True, "2", 2.5, None])
def test_a_bad_version_in_a_config_is_refused(bad):
    with pytest.raises(ValueError, match=r"TrainConfig.generator_version: generator version must be one of \(1, 2, 3\)"):
        TrainConfig(generator_version=bad)


@pytest.mark.parametrize("category", ["chair", "table", "airplane", "animal"])
def test_the_committed_networks_cards_and_recipes_name_their_version_and_the_pinned_recipes_version_1(category):
    card = json.loads((ROOT / "data_samples" / "checkpoints" / f"{category}.json").read_text())
    assert ("generator_version" in card["config"]) == (SHIPPED[category] > 1)
    assert TrainConfig.from_dict(card["config"]).generator_version == SHIPPED[category]
    assert course_config(category).generator_version == SHIPPED[category]
    path = ROOT / "data_samples" / "checkpoints" / "configs" / f"{category}.json"
    assert TrainConfig.load_json(path).generator_version == SHIPPED[category], path
    for path in (ROOT / "experiments" / "recipes" / "15min" / f"{category}.json",
                 ROOT / "experiments" / "recipes" / "15min" / "finetune" / f"{category}.json"):
        if path.is_file():
            assert TrainConfig.load_json(path).generator_version == 1, path


def test_the_config_version_chooses_the_shapes(tmp_path, monkeypatch):
    monkeypatch.setenv("CUBOIDLIB_CACHE", str(tmp_path))
    for version in (1, 2):
        config = DataConfig(category="animal", n_shapes=3, n_points=64, generator_version=version)
        expected = make_collection("animal", 3, 64, use_cache=False, version=version)
        assert (load_shapes(config).points.numpy() == expected.points).all()


def _train_config(argv):
    from cuboidlib.cli import build_parser
    from cuboidlib.cli_train import _train_config_from_args

    return _train_config_from_args(build_parser().parse_args(["train", "--out", "run", *argv]))


def test_the_train_command_reads_a_config_file_without_the_field_as_version_1(tmp_path):
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"category": "animal", "n_shapes": 10}))
    assert _train_config([]).generator_version == 3
    assert _train_config(["--config", str(old)]).generator_version == 1
    assert _train_config(["--config", str(old), "--generator-version", "2"]).generator_version == 2
    new = tmp_path / "new.json"
    new.write_text(json.dumps({"category": "animal", "generator_version": 2}))
    assert _train_config(["--config", str(new)]).generator_version == 2


def test_evaluate_scores_on_the_networks_version_and_says_which(monkeypatch, capsys):
    import cuboidlib.dataset
    from cuboidlib.cli import main

    seen, load = [], cuboidlib.dataset.load_shapes

    def few(config, progress=False):  # the first 12 shapes of the network's collection: 3 test shapes
        seen.append(config.generator_version)
        return load(config.replace(n_shapes=12))

    monkeypatch.setattr(cuboidlib.dataset, "load_shapes", few)
    base = ["evaluate", "animal", "--device", "cpu", "--samples", "64"]
    assert main(base) == 0  # the committed card has no generator_version: version 1
    assert "animal: animal, generator version 1, test split" in capsys.readouterr().out
    assert main([*base, "--generator-version", "2"]) == 0
    assert "animal: animal, generator version 2, test split" in capsys.readouterr().out
    assert seen == [1, 2]
    with pytest.raises(SystemExit, match="2"):
        main(["evaluate", "animal", "--generator-version", "4"])
    assert "invalid choice: 4 (choose from 1, 2, 3)" in capsys.readouterr().err
    assert main(["evaluate", "animal", "--generator-version", "2", "--data-dir", "."]) != 0
    assert "--generator-version chooses procedural shapes" in capsys.readouterr().err
