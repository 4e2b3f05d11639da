"""The library's structure: data flows down.

``LAYERS`` is the one place where the order of cuboidlib's modules is written down. A module may import
only modules of lower layers. Every import counts: at the top of a file, inside a function, or under
``TYPE_CHECKING``. A function-local import of a cuboidlib module must say on its line why it waits (start-up
time), so that one is never used to hide a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "cuboidlib"

#: cuboidlib's modules from the bottom up. Each line is a layer; a module imports only from the lines above it.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("__init__", "files"),                                    # version, reading and writing files
    ("_checks", "config", "kernels", "file_tables"),          # plumbing: checks, configs, C++, text and PLY tables
    ("rotations",),                                           # quaternions and rotation matrices
    ("neighbors", "geometry", "normalization", "solids", "mesh_files"),  # kNN, cuboids, the unit frame, solids, meshes
    ("shapes_common",),                                       # what the procedural categories build with
    ("shapes_chair", "shapes_table", "shapes_airplane", "shapes_animal"),  # one procedural category each
    ("normals", "distance", "metrics", "shapes", "thin_shapes", "edgeconv_fast", "frames"),  # Eq. (5), scores, shapes, frames
    ("losses", "model", "io", "viz"),                         # Eqs. (4)-(9), the network (Sec. 3), files, figures
    ("checkpoint", "export", "toy2d", "dataset", "sample_files"),  # weights, result files, the 2D toy, data sets, samples
    ("export_view", "toy2d_measures"),                        # HTML views of result files; the 2D toy's measures
    ("results", "runs"),                                      # the result types; a run's bookkeeping
    ("applications", "baseline", "merging", "counting"),      # networks' uses (Sec. 4.4), k-means boxes, merging, the count
    ("fitting", "evaluation", "network_check", "train_config"),  # the per-shape fit, the test-split scores, the network check, the training config
    ("abstraction", "train"),                                 # the one pipeline, the training loop (Sec. 3.4.5)
    ("release",),                                             # a trained run -> a committed network and card
    ("cli_common",),                                          # what the commands share: errors, inputs, outputs
    ("cli_shapes", "cli_train"),                              # the command line's runs over shapes; its network commands
    ("cli",),                                                 # the command-line tool
    ("__main__",),                                            # python -m cuboidlib
)


def _modules() -> set[str]:
    return {p.stem for p in PACKAGE.glob("*.py")}


def _imports(path: Path, modules: set[str]) -> list[tuple[int, str, bool]]:
    """(line, imported module, inside a function) for every import of a cuboidlib module in ``path``."""
    tree = ast.parse(path.read_text())
    local = {id(node) for fn in ast.walk(tree) if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef))
             for node in ast.walk(fn)}
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            if node.module:
                names = [node.module.split(".")[0]]
            else:  # from . import x: a module, or a name of the package's __init__
                names = [a.name if a.name in modules else "__init__" for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("cuboidlib"):
            parts = node.module.split(".")
            names = [parts[1]] if len(parts) > 1 else [a.name if a.name in modules else "__init__" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name.split(".")[1] for a in node.names if a.name.startswith("cuboidlib.")]
        found += [(node.lineno, name, id(node) in local) for name in names if name in modules]
    return found


def test_every_module_has_one_layer():
    listed = [m for layer in LAYERS for m in layer]
    assert len(listed) == len(set(listed)), "a module is listed twice"
    assert set(listed) == _modules(), f"unlisted: {_modules() - set(listed)}; gone: {set(listed) - _modules()}"


@pytest.mark.parametrize("module", sorted(_modules()))
def test_a_module_imports_only_lower_layers(module):
    level = {m: k for k, layer in enumerate(LAYERS) for m in layer}
    upward = [f"line {line}: {name} (layer {level[name]})" for line, name, _ in _imports(PACKAGE / f"{module}.py",
                                                                                          _modules())
              if name != module and level[name] >= level[module]]
    assert not upward, f"cuboidlib/{module}.py (layer {level[module]}) imports from its own or a higher layer: {upward}"


def test_function_local_imports_say_why():
    lines_without_reason = []
    for path in sorted(PACKAGE.glob("*.py")):
        source = path.read_text().splitlines()
        for line, name, inside in _imports(path, _modules()):
            if inside and "#" not in source[line - 1]:
                lines_without_reason.append(f"{path.name}:{line} ({name})")
    assert not lines_without_reason, ("function-local imports of cuboidlib modules must say why on their line "
                                      f"(start-up time): {lines_without_reason}")


def test_the_checker_sees_local_and_type_checking_imports(tmp_path):
    source = ("from typing import TYPE_CHECKING\nfrom . import __version__\nif TYPE_CHECKING:\n"
              "    from .train import TrainConfig\n\ndef f():\n    from .model import ModelConfig  # start-up time\n")
    (tmp_path / "probe.py").write_text(source)
    assert _imports(tmp_path / "probe.py", {"train", "model", "__init__"}) == [
        (2, "__init__", False), (4, "train", False), (7, "model", True)]
