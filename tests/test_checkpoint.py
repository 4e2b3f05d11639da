from pathlib import Path

import pytest
import torch

import cuboidlib
from cuboidlib.checkpoint import (
    FORMAT,
    CheckpointMismatch,
    check_config_matches,
    config_differences,
    load_checkpoint,
    load_model,
    save_checkpoint,
)
from cuboidlib.model import CuboidAbstractionNet, ModelConfig

TINY = ModelConfig.small(num_cuboids=3, k=4, edge_dims=(4,), global_dim=8, latent_dim=4, cuboid_code_dim=4,
                         cuboid_feature_dims=(8,), exist_hidden_dim=4, seg_dim=4)


def _model(seed: int = 0, config: ModelConfig = TINY) -> CuboidAbstractionNet:
    torch.manual_seed(seed)
    return CuboidAbstractionNet(config)


def _save(path, model, **extra) -> Path:
    return save_checkpoint(path, {"model": model.config.to_dict(), "lr": 6e-4}, model.state_dict(), **extra)


def test_checkpoint_round_trip_with_plain_weights_only_loading(tmp_path):
    model = _model()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    model(torch.randn(2, 16, 3)).centers.sum().backward()
    opt.step()
    gen = torch.Generator().manual_seed(5)
    path = _save(tmp_path / "run" / "last.pt", model, optimizer=opt.state_dict(), step=7,
                 rng={"loss": [gen.get_state()]}, best_val=None)
    raw = torch.load(path, weights_only=True)  # loads without allowing any code
    assert raw["format"] == FORMAT and raw["library_version"] == cuboidlib.__version__ and raw["step"] == 7
    state = load_checkpoint(path)
    for k, v in model.state_dict().items():
        assert torch.equal(state["model"][k], v)
    opt2 = torch.optim.Adam(_model(1).parameters(), lr=1e-3)
    opt2.load_state_dict(state["optimizer"])
    assert torch.equal(torch.Generator().set_state(state["rng"]["loss"][0]).get_state(), gen.get_state())
    assert not list(path.parent.glob("*.tmp"))  # written through a temporary file, then renamed


def test_load_model_rebuilds_the_network_in_eval_mode(tmp_path):
    model = _model(3)
    path = _save(tmp_path / "m.pt", model)
    loaded, state = load_model(path)
    assert not loaded.training and loaded.config == TINY
    x = torch.randn(2, 16, 3)
    model.eval()
    torch.testing.assert_close(loaded(x).centers, model(x).centers, rtol=0, atol=0)
    loaded_again, _ = load_model(path, config=TINY)  # the matching config is accepted
    assert loaded_again.config == TINY


def test_a_checkpoint_with_another_model_config_is_refused(tmp_path):
    path = _save(tmp_path / "m.pt", _model())
    other = ModelConfig.from_dict({**TINY.to_dict(), "num_cuboids": 5, "seg_dim": 6})
    with pytest.raises(CheckpointMismatch, match=r"num_cuboids: checkpoint has 3, requested 5.*seg_dim: checkpoint has 4"):
        load_model(path, config=other)


def test_weights_that_do_not_fit_the_stored_config_are_refused(tmp_path):
    model = _model()
    state = model.state_dict()
    state["extra.weight"] = torch.zeros(1)
    path = save_checkpoint(tmp_path / "m.pt", {"model": TINY.to_dict()}, state)
    with pytest.raises(ValueError, match=r"(?s)weights do not fit the stored model config.*Unexpected key"):  # strict
        load_model(path)


def test_config_differences_are_listed_by_dotted_name():
    stored = {"lr": 6e-4, "model": {"k": 20, "edge_dims": [64, 64]}, "split": [0.7, 0.1, 0.2]}
    same = {"lr": 6e-4, "model": {"k": 20, "edge_dims": (64, 64)}, "split": (0.7, 0.1, 0.2)}  # tuples = lists
    assert config_differences(stored, same) == []
    other = {"lr": 1e-3, "model": {"k": 16, "edge_dims": [64, 64]}, "seed": 1}
    diffs = config_differences(stored, other)
    assert diffs == [
        "lr: checkpoint has 0.0006, requested 0.001",
        "model.k: checkpoint has 20, requested 16",
        "seed: missing in the checkpoint, requested 1",
        "split: [0.7, 0.1, 0.2] in the checkpoint, not in the requested config",
    ]
    with pytest.raises(CheckpointMismatch, match=r"training config does not match the checkpoint \(4 difference"):
        check_config_matches(stored, other, "training config")


def test_values_that_need_code_to_load_are_refused_when_saving(tmp_path):
    model = _model()
    with pytest.raises(TypeError, match=r"checkpoint.where is a PosixPath"):
        _save(tmp_path / "m.pt", model, where=Path("/tmp"))
    with pytest.raises(TypeError, match="is a Generator"):
        _save(tmp_path / "m.pt", model, rng=torch.Generator())
    assert not (tmp_path / "m.pt").exists()


def test_non_finite_weights_are_never_written_over_a_good_checkpoint(tmp_path):
    model = _model()
    path = _save(tmp_path / "m.pt", model)
    good = path.read_bytes()
    with torch.no_grad():
        next(model.parameters())[0] = float("nan")
    with pytest.raises(ValueError, match="holds NaN or infinite values; refusing to save"):
        _save(path, model)
    assert path.read_bytes() == good


class _Payload:
    """An object whose unpickling would create a file (what a malicious checkpoint could do)."""

    def __init__(self, target):
        self.target = str(target)

    def __reduce__(self):
        return (open, (self.target, "w"))


def test_files_that_would_run_code_or_are_not_checkpoints_are_refused(tmp_path):
    marker = tmp_path / "pwned"
    torch.save({"format": FORMAT, "payload": _Payload(marker)}, tmp_path / "evil.pt")
    with pytest.raises(ValueError, match=r"weights_only=True"):
        load_checkpoint(tmp_path / "evil.pt")
    assert not marker.exists()
    torch.save({"weights": torch.zeros(2)}, tmp_path / "plain.pt")
    with pytest.raises(ValueError, match="not a cuboidlib checkpoint"):
        load_checkpoint(tmp_path / "plain.pt")
    good = _save(tmp_path / "good.pt", _model())
    (tmp_path / "cut.pt").write_bytes(good.read_bytes()[:200])
    with pytest.raises(ValueError, match="not a readable cuboidlib checkpoint"):
        load_checkpoint(tmp_path / "cut.pt")
    with pytest.raises(FileNotFoundError, match="no such checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    torch.save({"format": FORMAT, "format_version": 99, "library_version": "9", "config": {"model": {}}, "model": {}},
               tmp_path / "future.pt")
    with pytest.raises(ValueError, match="newer than this library"):
        load_checkpoint(tmp_path / "future.pt")
