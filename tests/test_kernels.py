"""The compiled kernels (cuboidlib/kernels.cpp) against the Python code they replace.

FastEdgeConv with the kernels against the readable EdgeConv: tests/test_model.py, in the test of the
fast layer, parametrised over ``compiled``.

Skipped where no C++ compiler or ninja is found (cuboidlib.kernels.available()); a build error where
they are found fails here.
"""

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from cuboidlib import kernels
from cuboidlib.edgeconv_fast import FastEdgeConv, _EdgeMLP
from cuboidlib.losses import LossConfig, total_loss
from cuboidlib.model import CuboidAbstractionNet, ModelConfig
from cuboidlib.neighbors import knn_indices
from cuboidlib.train import Trainer
from cuboidlib.train_config import TrainConfig

needs_compiler = pytest.mark.skipif(not kernels.available(), reason="no C++ compiler or ninja here")


@pytest.fixture
def compiled():
    """The compiled kernels enabled for one test (disabled afterwards, whatever happens)."""
    kernels.enable()
    yield kernels.ops()
    kernels.disable()


def _same_sets(a, b):
    return torch.equal(a.sort(-1).values, b.sort(-1).values)


# ----------------------------------------------------------------------------------------------
# smallest_k: the top-k selection of knn_indices
# ----------------------------------------------------------------------------------------------


@needs_compiler
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("n, k", [(1024, 20), (100, 20), (37, 5), (20, 20), (300, 1)])
def test_smallest_k_selects_the_same_entries_as_topk(compiled, dtype, n, k):
    g = torch.Generator().manual_seed(n + k)
    d = torch.rand(17, n, generator=g, dtype=dtype)
    chosen = compiled.smallest_k(d, k)
    assert chosen.shape == (17, k) and chosen.dtype == torch.long
    assert _same_sets(chosen, d.topk(k, dim=1, largest=False).indices)


@needs_compiler
def test_smallest_k_reads_strided_rows_and_survives_non_finite_rows(compiled):
    d = torch.rand(5, 64, generator=torch.Generator().manual_seed(0))
    wide = torch.full((5, 80), math.inf)
    wide[:, :64] = d
    assert _same_sets(compiled.smallest_k(wide[:, :64], 8), d.topk(8, dim=1, largest=False).indices)
    bad = d.clone()
    bad[0] = math.nan
    bad[1, :60] = math.nan
    bad[2] = math.inf
    chosen = compiled.smallest_k(bad, 8)
    assert ((chosen >= 0) & (chosen < 64)).all()
    assert all(len(set(row.tolist())) == 8 for row in chosen)  # k distinct valid indices per row
    assert set(chosen[1].tolist()) >= {60, 61, 62, 63}  # the finite entries of a mostly-NaN row first


@needs_compiler
def test_smallest_k_rejects_bad_arguments(compiled):
    with pytest.raises(RuntimeError, match="k must be"):
        compiled.smallest_k(torch.rand(3, 10), 11)
    with pytest.raises(RuntimeError, match="unit column stride"):
        compiled.smallest_k(torch.rand(10, 3).T, 2)


@needs_compiler
@pytest.mark.parametrize("channels", [3, 64])
def test_knn_indices_are_the_same_with_the_compiled_selection(channels):
    x = torch.randn(3, 500, channels, generator=torch.Generator().manual_seed(channels))
    reference = knn_indices(x, 20)
    kernels.enable()
    try:
        fast = knn_indices(x, 20)
        ordered = knn_indices(x, 20, sorted=True)  # asks for an order: torch.topk, as before
    finally:
        kernels.disable()
    assert _same_sets(fast, reference)
    assert (fast == torch.arange(500).view(1, 500, 1)).any(-1).all()  # every point is its own neighbour
    assert torch.equal(ordered, knn_indices(x, 20, sorted=True))


# ----------------------------------------------------------------------------------------------
# The per-edge loops of _EdgeMLP and _edge_stats
# ----------------------------------------------------------------------------------------------


def _edge_inputs(dtype, R=40, C1=6, C2=7, k=5):
    g = torch.Generator().manual_seed(3)

    def rand(*shape):
        return torch.randn(*shape, generator=g, dtype=dtype)

    nbr = torch.randint(0, R, (R, k), generator=g)
    return dict(P=rand(R, C1), Q=rand(R, C1), nbr=nbr, W2=rand(C2, C1), shift=rand(C2), gamma=rand(C1),
                beta=rand(C1), W2_var=rand(C2, C1), c_mean=rand(C2), g_hmax=rand(R, C2))


@needs_compiler
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("rows", [3, 40])  # several chunks, one partial; one chunk
def test_edge_mlp_chunk_loops_match_the_python_ones(compiled, dtype, rows):
    e = _edge_inputs(dtype)
    tol = dict(rtol=1e-12, atol=1e-12) if dtype == torch.float64 else dict(rtol=1e-5, atol=1e-5)
    forward_args = (e["P"], e["Q"], e["nbr"], e["W2"], e["shift"], 0.2, rows)
    hmax, harg, s1, s2 = compiled.edge_mlp_forward(*forward_args)
    hmax_py, harg_py, s1_py, s2_py = _EdgeMLP._forward_chunks(*forward_args)
    torch.testing.assert_close(hmax, hmax_py, **tol)
    assert torch.equal(harg, harg_py)
    torch.testing.assert_close(s1, s1_py, **tol)
    torch.testing.assert_close(s2, s2_py, **tol)
    for batch_stats in (True, False):
        args = (e["P"], e["Q"], e["nbr"], e["gamma"], e["beta"], e["W2"], e["W2_var"], e["c_mean"], harg,
                e["g_hmax"], 0.2, rows, batch_stats)
        ours, python = compiled.edge_mlp_backward(*args), _EdgeMLP._backward_chunks(*args)
        for name, a, b in zip(("g_W2", "g_rowsum", "g_scatter", "x_scatter"), ours, python):
            if b is None:
                assert a is None, name
            else:
                torch.testing.assert_close(a, b, **tol, msg=name)


@needs_compiler
def test_edge_stats_match_the_python_sums(compiled):
    e = _edge_inputs(torch.float32, R=300, C1=16)
    kernels.disable()
    reference = FastEdgeConv._edge_stats(e["P"], e["Q"], e["nbr"], 7)
    kernels.enable()
    ours = FastEdgeConv._edge_stats(e["P"], e["Q"], e["nbr"], 7)
    for a, b in zip(ours, reference):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


# ----------------------------------------------------------------------------------------------
# The layer and the network
# ----------------------------------------------------------------------------------------------


@needs_compiler
def test_float32_gradients_of_the_compiled_backward_stay_accurate():
    # The compiled backward sums v v^T and v over all edges instead of the per-edge dL/dh (two
    # products per chunk instead of three); u = v - LeakyReLU(beta1) keeps the float32 sums accurate
    # when v has a large mean (BatchNorm bias 3 here). Both versions against float64.
    torch.manual_seed(0)
    conv = FastEdgeConv(32, 32, k=20)
    with torch.no_grad():
        conv.bn1.bias.fill_(3.0)
    x = torch.randn(2, 512, 32) * 0.5 + 2.0
    g = torch.randn(2, 512, 32)

    def gradients(dtype, use):
        m = FastEdgeConv(32, 32, k=20).to(dtype)
        m.load_state_dict(conv.state_dict())
        (kernels.enable if use else kernels.disable)()
        try:
            xx = x.to(dtype, copy=True).requires_grad_()
            (m(xx) * g.to(dtype)).sum().backward()
        finally:
            kernels.disable()
        return [xx.grad.double()] + [p.grad.double() for p in m.parameters()]

    exact = gradients(torch.float64, False)
    for use in (False, True):
        for a, b in zip(gradients(torch.float32, use), exact):
            assert (a - b).abs().max() <= 1e-3 * b.abs().max()


@needs_compiler
def test_training_step_of_the_network_is_the_same_with_kernels():
    config = ModelConfig.small(num_cuboids=4)
    # points on the unit sphere, whose normals are the points themselves
    points = torch.nn.functional.normalize(torch.randn(2, 256, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    results = []
    for use in (False, True):
        (kernels.enable if use else kernels.disable)()
        try:
            torch.manual_seed(0)
            net = CuboidAbstractionNet(config).double().train()
            out = net(points.double())
            loss = total_loss(out, points.double(), points.double(), LossConfig(), generator=torch.Generator().manual_seed(1)).total
            loss.backward()
            results.append((loss.detach(), [p.grad.clone() for p in net.parameters()]))
        finally:
            kernels.disable()
    torch.testing.assert_close(results[0][0], results[1][0], rtol=1e-10, atol=1e-12)
    for a, b in zip(results[0][1], results[1][1]):
        torch.testing.assert_close(a, b, rtol=1e-8, atol=1e-10)


@needs_compiler
def test_trainer_enables_the_kernels_from_its_config(tmp_path):
    config = TrainConfig(category="chair", n_shapes=8, n_points=128, model=ModelConfig.small(num_cuboids=4),
                         batch_size=4, max_steps=1, checkpoint_every=1, validate_every=1, compiled_kernels=True)
    try:
        Trainer(config, tmp_path / "run", quiet=True).run()
        assert kernels.enabled()
    finally:
        kernels.disable()
    assert (tmp_path / "run" / "best.pt").is_file()


# ----------------------------------------------------------------------------------------------
# Without a compiler
# ----------------------------------------------------------------------------------------------


@needs_compiler
def test_by_default_the_first_use_builds_and_uses_the_kernels(monkeypatch):
    monkeypatch.delenv(kernels.ENV)
    monkeypatch.setattr(kernels, "_enabled", None)
    assert kernels.enabled()


def test_by_default_without_a_compiler_one_line_says_so_and_the_python_code_runs(monkeypatch, capsys):
    monkeypatch.delenv(kernels.ENV)
    monkeypatch.setattr(kernels, "_enabled", None)
    monkeypatch.setattr(kernels, "_module", None)
    monkeypatch.setattr(kernels, "_compiler", lambda: None)
    assert not kernels.enabled()
    assert not kernels.enabled(), "decided once"
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "compiled kernels are not used (no C++ compiler" in lines[0]


@pytest.mark.parametrize("value", ["0", "off", "no"])
def test_the_environment_turns_the_kernels_off(monkeypatch, value):
    monkeypatch.setenv(kernels.ENV, value)
    monkeypatch.setattr(kernels, "_enabled", None)
    assert not kernels.enabled()


def test_enable_without_a_compiler_says_so_and_leaves_the_python_code_on(monkeypatch):
    monkeypatch.setattr(kernels, "_module", None)
    monkeypatch.setattr(kernels, "_compiler", lambda: None)
    with pytest.raises(kernels.KernelsUnavailable, match="no C\\+\\+ compiler"):
        kernels.enable()
    assert not kernels.enabled()
    assert not kernels.available()


def test_train_config_rejects_a_non_boolean_switch():
    with pytest.raises(ValueError, match="compiled_kernels must be true, false or null"):
        TrainConfig(compiled_kernels="yes")


# ----------------------------------------------------------------------------------------------
# The build: a folder per source, flags, compiler, torch and Python; the project's own lock
# ----------------------------------------------------------------------------------------------


def _hold_lock(path, pid_text="4242"):
    """A separate process that holds an exclusive flock on ``path`` until it is killed (as a build does)."""
    code = ("import fcntl, sys, time\n"
            "f = open(sys.argv[1], 'a+'); fcntl.flock(f.fileno(), fcntl.LOCK_EX)\n"
            "f.seek(0); f.truncate(); f.write(sys.argv[2] + '\\n'); f.flush()\n"
            "print('locked', flush=True); time.sleep(120)\n")
    process = subprocess.Popen([sys.executable, "-c", code, str(path), pid_text], stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "locked"
    return process


needs_flock = pytest.mark.skipif(sys.platform == "win32", reason="the build lock is a POSIX flock")


@needs_flock
@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL])
def test_a_lock_whose_process_is_gone_is_taken_over_at_once(tmp_path, how):
    path = tmp_path / "k.lock"
    holder = _hold_lock(path)
    holder.send_signal(how)
    holder.wait(timeout=30)
    start = time.monotonic()
    with kernels._BuildLock(path):
        assert path.read_text().split() == [str(os.getpid())], "the lock file names its holder"
    assert time.monotonic() - start < 5


@needs_flock
def test_a_live_lock_is_waited_for_with_a_notice_then_the_python_code_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    monkeypatch.delenv(kernels.ENV, raising=False)
    monkeypatch.setattr(kernels, "_enabled", None)
    monkeypatch.setattr(kernels, "_module", None)
    monkeypatch.setattr(kernels, "available", lambda: True)
    monkeypatch.setattr(kernels, "_compiler", lambda: "/usr/bin/c++")
    monkeypatch.setattr("torch.utils.cpp_extension.is_ninja_available", lambda: True)
    monkeypatch.setattr(kernels, "LOCK_WAIT_SECONDS", 1.0)
    monkeypatch.setattr(kernels, "LOCK_NOTICE_SECONDS", 0.3)
    name, _ = kernels._build_flags()
    holder = _hold_lock(tmp_path / f"{name}.lock", "4242")
    try:
        assert not kernels.enabled()
    finally:
        holder.kill()
        holder.wait(timeout=30)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2, lines
    assert "waiting for another process (pid 4242)" in lines[0] and f"{name}.lock" in lines[0]
    assert "compiled kernels are not used" in lines[1] and "pid 4242" in lines[1] and "PyTorch code runs" in lines[1]


@pytest.mark.parametrize("leftover", [True, False])
def test_a_build_never_waits_on_the_lock_file_pytorch_leaves_behind(tmp_path, monkeypatch, leftover):
    """torch's FileBaton ``lock`` records no process: one left by a killed build made load() wait forever."""
    folder = tmp_path / "cuboidlib_kernels_x"
    folder.mkdir()
    if leftover:
        (folder / "lock").write_text("")
    seen = {}

    def fake_load(name, sources, extra_cflags, build_directory, verbose):
        seen["lock"] = (Path(build_directory) / "lock").exists()
        seen["folder"] = build_directory
        return "module"

    monkeypatch.setattr("torch.utils.cpp_extension.load", fake_load)
    assert kernels._load("cuboidlib_kernels_x", ["-O3"], folder) == "module"
    assert seen == {"lock": False, "folder": str(folder)}


def test_every_checkout_builds_from_the_same_source_path(tmp_path, monkeypatch):
    """ninja rebuilds when the compile command changes, and the command names the source: two checkouts in two
    folders would rebuild the same kernels in turn. The build reads a copy of the source kept in its folder."""
    folder = tmp_path / "cuboidlib_kernels_x"
    folder.mkdir()
    seen = []
    monkeypatch.setattr("torch.utils.cpp_extension.load",
                        lambda name, sources, extra_cflags, build_directory, verbose: seen.append(sources) or "module")
    kernels._load("cuboidlib_kernels_x", ["-O3"], folder)
    copy = folder / kernels._SOURCE.name
    assert seen == [[str(copy)]] and copy.read_bytes() == kernels._SOURCE.read_bytes()
    stamp = copy.stat().st_mtime_ns
    other = tmp_path / "other_checkout" / kernels._SOURCE.name  # the same source in another folder
    other.parent.mkdir()
    other.write_bytes(kernels._SOURCE.read_bytes())
    monkeypatch.setattr(kernels, "_SOURCE", other)
    kernels._load("cuboidlib_kernels_x", ["-O3"], folder)
    assert seen[1] == [str(copy)] and copy.stat().st_mtime_ns == stamp  # the copy is not rewritten
    assert [p.name for p in folder.iterdir()] == [copy.name]  # no temporary file left


def test_a_failed_build_raises_kernels_unavailable_with_the_cause(tmp_path, monkeypatch):
    def failing_load(*args, **kwargs):
        raise RuntimeError("Error building extension: g++ exited with 1")

    monkeypatch.setattr("torch.utils.cpp_extension.load", failing_load)
    with pytest.raises(kernels.KernelsUnavailable, match="failed: Error building extension"):
        kernels._load("n", [], tmp_path)


def test_the_build_folder_is_named_by_the_source_flags_torch_and_python(tmp_path, monkeypatch):
    name, flags = kernels._build_flags()
    assert name.startswith("cuboidlib_kernels_") and name.isidentifier()
    assert kernels._build_flags() == (name, flags), "the same inputs give the same name"
    names = {name}
    edited = tmp_path / "kernels.cpp"
    edited.write_bytes(kernels._SOURCE.read_bytes() + b"\n// edited\n")
    with monkeypatch.context() as m:
        m.setattr(kernels, "_SOURCE", edited)
        names.add(kernels._build_flags()[0])
    with monkeypatch.context() as m:
        m.setattr(torch, "__version__", "0.0.0")
        names.add(kernels._build_flags()[0])
    with monkeypatch.context() as m:
        other_abi = not torch.compiled_with_cxx11_abi()
        m.setattr(torch, "compiled_with_cxx11_abi", lambda: other_abi)
        names.add(kernels._build_flags()[0])
    with monkeypatch.context() as m:
        m.setitem(kernels._VECTOR_FLAGS, torch.backends.cpu.get_cpu_capability(), ["-mfake"])
        names.add(kernels._build_flags()[0])
    with monkeypatch.context() as m:
        m.setattr(kernels, "_compiler", lambda: "/opt/other/clang++")
        names.add(kernels._build_flags()[0])
    assert len(names) == 6, "each input changes the folder's name"


@pytest.mark.parametrize("value", ["garbage", "2", "enable", "o n"])
def test_an_unknown_environment_value_is_refused_with_the_choices(monkeypatch, value):
    monkeypatch.setenv(kernels.ENV, value)
    monkeypatch.setattr(kernels, "_enabled", None)
    with pytest.raises(ValueError, match=f"{kernels.ENV}=.* is not understood; expected one of 0, off"):
        kernels.enabled()


def test_the_environment_asking_for_the_kernels_raises_where_they_cannot_be_built(monkeypatch):
    monkeypatch.setenv(kernels.ENV, "1")
    monkeypatch.setattr(kernels, "_enabled", None)
    monkeypatch.setattr(kernels, "_module", None)
    monkeypatch.setattr(kernels, "_compiler", lambda: None)
    with pytest.raises(kernels.KernelsUnavailable, match="no C\\+\\+ compiler"):
        kernels.enabled()
