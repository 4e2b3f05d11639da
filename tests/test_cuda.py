"""The library on a CUDA GPU gives what it gives on the CPU. Skipped on machines without one.

Every computation of cuboidlib is device-agnostic; these tests run the parts that matter on CUDA and
compare with the CPU in float64: the kNN graph, the fast network (values and gradients, against the
readable one on the CPU), the paper's first EdgeConv at full size (in the GPU's larger chunks), the
distance of Eq. (5), and short training runs whose checkpoint, and whose release (translation-head fit
and test scores on the GPU), then load on the CPU.
"""

from __future__ import annotations

import copy
import dataclasses

import pytest
import torch

from cuboidlib.checkpoint import load_model
from cuboidlib.dataset import load_splits
from cuboidlib.distance import point_to_cuboid_distance
from cuboidlib.edgeconv_fast import FastEdgeConv
from cuboidlib.model import CuboidAbstractionNet, ModelConfig
from cuboidlib.neighbors import knn_indices
from cuboidlib.train import Trainer
from cuboidlib.train_config import TrainConfig

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")

CUDA = "cuda"
SMALL = ModelConfig.small(num_cuboids=6, k=8, edge_dims=(16, 16), global_dim=32, latent_dim=16, cuboid_code_dim=8,
                          cuboid_feature_dims=(32, 16), exist_hidden_dim=8, seg_dim=8)


def _cloud(batch=2, n=200, seed=0):
    g = torch.Generator().manual_seed(seed)
    normals = torch.nn.functional.normalize(torch.randn(batch, n, 3, generator=g, dtype=torch.float64), dim=-1)
    return 0.5 * normals + 0.05 * torch.randn(batch, n, 3, generator=g, dtype=torch.float64), normals


def test_knn_graph_on_cuda_is_the_cpus():
    x = torch.randn(2, 500, 64, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    on_cpu = knn_indices(x, 20, sorted=True)
    on_cuda = knn_indices(x.to(CUDA), 20, sorted=True).cpu()
    assert on_cuda.shape == on_cpu.shape
    # the same neighbours: their distances agree (indices could only differ between exact ties)
    distances = torch.cdist(x, x)
    torch.testing.assert_close(distances.gather(2, on_cuda), distances.gather(2, on_cpu))


@pytest.mark.parametrize("input_normals", ["none", "differences"])
def test_fast_network_on_cuda_matches_the_readable_one_on_the_cpu(input_normals):
    torch.manual_seed(0)
    config = dataclasses.replace(SMALL, input_normals=input_normals)
    readable = CuboidAbstractionNet(config, fast=False).double().train()
    fast = CuboidAbstractionNet(config, fast=True).double().train()
    fast.load_state_dict(readable.state_dict())
    fast.to(CUDA)
    points, normals = _cloud()
    weights = torch.linspace(-1, 1, 6, dtype=torch.float64)

    def scalar(net, device):
        # training mode (BatchNorm over the batch) with z = mu: no random draw differs between devices
        out = net(points.to(device), normals.to(device) if input_normals != "none" else None, sample_latent=False)
        return out, (out.mu.sum() + out.logvar.sum() + (out.centers * weights.to(device)[:, None]).sum()
                     + out.W.square().sum() + out.exist_logits.sum() + out.half_sizes.sum())

    out_cpu, loss_cpu = scalar(readable, "cpu")
    out_cuda, loss_cuda = scalar(fast, CUDA)
    for name in ("mu", "logvar", "centers", "half_sizes", "exist_logits", "W"):
        torch.testing.assert_close(getattr(out_cuda, name).cpu(), getattr(out_cpu, name), atol=1e-9, rtol=1e-9)
    loss_cpu.backward()
    loss_cuda.backward()
    for (name, p), q in zip(readable.named_parameters(), fast.parameters()):
        assert (p.grad is None) == (q.grad is None), name
        if p.grad is not None:
            torch.testing.assert_close(q.grad.cpu(), p.grad, atol=1e-9, rtol=1e-7, msg=f"gradient of {name}")
    for (name, b), c in zip(readable.named_buffers(), fast.buffers()):
        torch.testing.assert_close(c.cpu(), b, atol=1e-9, rtol=1e-9, msg=f"buffer {name}")


def test_paper_sized_edgeconv_on_cuda_is_the_cpus():
    """The paper's first EdgeConv on 32 shapes of 4096 points: 2.6 M edges, three of a GPU's chunks."""
    torch.manual_seed(0)
    conv = FastEdgeConv(3, 64, k=20).double().train()
    x = torch.randn(32, 4096, 3, dtype=torch.float64)
    neighbours = knn_indices(x, 20)
    upstream = torch.randn(32, 4096, 64, dtype=torch.float64)
    on_cuda = copy.deepcopy(conv).to(CUDA)
    assert on_cuda._chunk_rows(torch.device(CUDA)) * 20 * 2 < 32 * 4096 * 20, "several chunks"
    results = []
    for net, device in ((conv, "cpu"), (on_cuda, CUDA)):
        y = net(x.to(device), neighbours.to(device))
        (y * upstream.to(device)).sum().backward()
        results.append((y.cpu(), [p.grad.cpu() for p in net.parameters()], [b.cpu() for b in net.buffers()]))
    (y_cpu, grads_cpu, buffers_cpu), (y_cuda, grads_cuda, buffers_cuda) = results
    torch.testing.assert_close(y_cuda, y_cpu, atol=1e-9, rtol=1e-9)
    for g_cuda, g_cpu in zip(grads_cuda, grads_cpu):
        torch.testing.assert_close(g_cuda, g_cpu, atol=1e-8, rtol=1e-8)
    for b_cuda, b_cpu in zip(buffers_cuda, buffers_cpu):
        torch.testing.assert_close(b_cuda, b_cpu, atol=1e-9, rtol=1e-9)


def test_point_to_cuboid_distance_on_cuda_is_the_cpus():
    points, normals = _cloud(n=300)
    g = torch.Generator().manual_seed(2)
    centers = 0.3 * torch.randn(2, 5, 3, generator=g, dtype=torch.float64)
    quaternions = torch.nn.functional.normalize(torch.randn(2, 5, 4, generator=g, dtype=torch.float64), dim=-1)
    half_sizes = 0.05 + 0.2 * torch.rand(2, 5, 3, generator=g, dtype=torch.float64)
    offsets = 0.05 * torch.randn(2, 300, generator=g, dtype=torch.float64)
    args = (points, normals, centers, quaternions, half_sizes)
    on_cpu = point_to_cuboid_distance(*args, offsets=offsets)
    on_cuda = point_to_cuboid_distance(*(a.to(CUDA) for a in args), offsets=offsets.to(CUDA))
    assert on_cuda.device.type == "cuda"
    torch.testing.assert_close(on_cuda.cpu(), on_cpu, atol=1e-12, rtol=1e-10)


def test_a_run_trained_on_cuda_loads_and_runs_on_the_cpu(tmp_path):
    config = TrainConfig(category="chair", n_shapes=20, n_points=128, batch_size=4, max_steps=6, checkpoint_every=3,
                         validate_every=3, model=SMALL, seed=0, device=CUDA)
    result = Trainer(config, tmp_path, quiet=True, splits=load_splits(config)).run()
    assert result.step == 6
    model, _ = load_model(tmp_path / "best.pt")
    assert next(model.parameters()).device.type == "cpu"
    points, _ = _cloud(batch=1, n=128)
    out = model.eval()(points.float())
    assert torch.isfinite(out.centers).all() and torch.isfinite(out.W).all()


def test_a_run_trained_on_cuda_is_released_there_and_loads_on_the_cpu(tmp_path):
    # the release fits the translation head and scores the network on the GPU, the k-means baseline on the CPU
    from cuboidlib.losses import LossConfig
    from cuboidlib.release import publish_run, translation_head_error

    config = TrainConfig(category="chair", n_shapes=20, n_points=128, batch_size=4, max_steps=3, checkpoint_every=3,
                         validate_every=3, model=SMALL, loss=LossConfig(centers_from_allocation=True), seed=0,
                         device=CUDA)
    splits = load_splits(config)
    Trainer(config, tmp_path / "run", quiet=True, splits=splits).run()
    best = tmp_path / "run" / "best.pt"
    state = torch.load(best, weights_only=True)
    bias = [k for k in state["model"] if k.startswith("abstraction.D_cp.existence.") and k.endswith(".bias")][-1]
    state["model"][bias].fill_(5.0)  # every cuboid exists, so the translation head has cuboids to be fitted to
    torch.save(state, best)
    card = publish_run(tmp_path / "run", tmp_path / "net.pt", command="cuboidlib train (test)")
    released, _ = load_model(tmp_path / "net.pt")
    assert next(released.parameters()).device.type == "cpu"
    error = translation_head_error(released, splits["val"].points)
    assert error == pytest.approx(card["translation_head"]["rms_error_validation_after"], abs=1e-4)
    network = card["test"]["results"][0]
    assert card["test"]["n_shapes"] == len(splits["test"]) and network["n_ac"] > 0
    assert card["machine"]["gpu"] == torch.cuda.get_device_name(), "the card names the GPU"
