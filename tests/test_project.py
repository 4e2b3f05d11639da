"""Checks of the project itself: install metadata, the committed notebooks and README.

nbval runs every notebook (see pyproject's pytest options); these tests check what nbval cannot:
that each committed notebook was executed top to bottom from a fresh kernel, that it keeps its
outputs, and that it has the course's form.
"""

from __future__ import annotations

import json
import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
SOLUTIONS = sorted((ROOT / "notebooks" / "solutions").glob("*_solutions.ipynb"))

# PyPI name -> conda-forge name, where they differ.
CONDA_NAMES = {"torch": "pytorch-cpu"}


def _requirement_map(requirements: list[str]) -> dict[str, str]:
    out = {}
    for req in requirements:
        m = re.fullmatch(r"\s*([A-Za-z0-9_.\-]+)\s*(.*?)\s*", req)
        assert m, f"cannot parse requirement {req!r}"
        out[m.group(1).lower()] = m.group(2).replace(" ", "")
    return out


def _environment_packages() -> dict[str, str]:
    """Conda dependencies of environment.yml as {name: version spec} (python, pip and the pip block left out)."""
    packages, in_deps = {}, False
    for line in (ROOT / "environment.yml").read_text().splitlines():
        line = line.split("#", 1)[0].rstrip()
        if not line:
            continue
        if not line.startswith(" "):
            in_deps = line.startswith("dependencies:")
            continue
        m = re.fullmatch(r"  - ([A-Za-z0-9_.\-]+)\s*(\S*)", line)  # top-level list items only
        if in_deps and m and m.group(1) not in {"python", "pip"}:
            packages[m.group(1).lower()] = m.group(2)
    return packages


def test_environment_yml_lists_the_same_packages_as_pyproject():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = _requirement_map(project["dependencies"] + project["optional-dependencies"]["dev"])
    wanted = {CONDA_NAMES.get(name, name): spec for name, spec in wanted.items()}
    assert _environment_packages() == wanted


def test_environment_yml_installs_the_package_itself():
    text = (ROOT / "environment.yml").read_text()
    assert re.search(r"^\s+- -e \.\[dev\]\s*$", text, re.M), "environment.yml must pip-install -e .[dev]"
    assert "conda-forge" in text


def test_readme_has_install_open_and_test_commands_for_ci():
    readme = (ROOT / "README.md").read_text()
    for marker in ("<!-- ci:install -->", "<!-- ci:test -->"):
        assert marker in readme, f"README.md lost the {marker} marker that .ci/run reads"
    assert "jupyter lab notebooks/" in readme
    assert "torch==" in readme, "the install command must pin torch so pip takes the CPU wheel"


def test_course_has_lessons():
    assert NOTEBOOKS, "notebooks/ holds no lesson"


def test_readme_lists_every_lesson():
    readme = (ROOT / "README.md").read_text()
    for nb in NOTEBOOKS:
        assert f"notebooks/{nb.name}" in readme, f"README.md does not list {nb.name}"


def test_readme_lesson_times_are_the_committed_course_run():
    """README's lesson table gives each lesson's run time as benchmarks/README.md records bench_course.py's run."""
    readme = (ROOT / "README.md").read_text()
    table = readme[readme.index("| lesson | what you learn | run time |"):]
    rows = [line for line in table[:table.index("\n\n")].splitlines()[2:]]
    assert len(rows) == len(NOTEBOOKS), "one row per lesson"
    course = next(line for line in (ROOT / "benchmarks" / "README.md").read_text().splitlines()
                  if line.startswith("| the whole course, every lesson top to bottom"))
    for row in rows:
        lesson, seconds = re.search(r"notebooks/(\d\w*?)_", row).group(1), row.rstrip(" |").rsplit("| ", 1)[1]
        assert re.search(rf"\b{re.escape(seconds)}\b", course), f"lesson {lesson}: {seconds!r} is not in bench_course's row"


def _heading_anchors(path: Path) -> set[str]:
    """The anchors GitHub gives the headings of a Markdown file: lower case, punctuation dropped, spaces to '-'."""
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in re.findall(r"^#+ (.*)$", text, re.M)}


def test_the_front_pages_link_only_to_what_exists():
    """Every relative link of README.md and docs/*.md names a file of the repository, and an anchor of a Markdown
    file names one of its headings."""
    broken = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            file = page.parent / path if path else page
            if not file.exists() or (anchor and file.suffix == ".md" and anchor not in _heading_anchors(file)):
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, broken


def test_the_front_figure_is_drawn_by_its_script(tmp_path):
    """docs/make_front_figure.py draws README's figure from a sample mesh and a committed network, and names the
    sample meshes when asked for one that does not exist."""
    import importlib.util

    assert "(docs/front.png)" in (ROOT / "README.md").read_text() and (ROOT / "docs" / "front.png").is_file()
    spec = importlib.util.spec_from_file_location("make_front_figure", ROOT / "docs" / "make_front_figure.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    out = tmp_path / "front.png"
    assert script.main(["--shapes", "table_0", "--out", str(out), "--dpi", "40"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(SystemExit, match="chair_0"):
        script.main(["--shapes", "sofa_0", "--out", str(tmp_path / "sofa.png")])
    assert not (tmp_path / "sofa.png").exists()


def _cells(nb_path: Path) -> list[dict]:
    return json.loads(nb_path.read_text())["cells"]


def _source(cell: dict) -> str:
    src = cell["source"]
    return src if isinstance(src, str) else "".join(src)


@pytest.mark.parametrize("nb_path", NOTEBOOKS + SOLUTIONS, ids=lambda p: p.name)
def test_notebook_was_executed_in_order_from_a_fresh_kernel(nb_path):
    code = [c for c in _cells(nb_path) if c["cell_type"] == "code"]
    counts = [c.get("execution_count") for c in code]
    assert counts == list(range(1, len(code) + 1)), (
        f"{nb_path.name}: execution counts {counts} are not 1, 2, 3, ...; re-run it top to bottom from a "
        "fresh kernel: jupyter nbconvert --to notebook --execute --inplace " + str(nb_path.relative_to(ROOT))
    )
    errors = [o for c in code for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors, f"{nb_path.name}: committed with error outputs"
    assert any(c.get("outputs") for c in code), f"{nb_path.name}: committed without outputs"


@pytest.mark.parametrize("nb_path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_has_the_course_form(nb_path):
    cells = _cells(nb_path)
    first = _source(cells[0]).lower()
    assert cells[0]["cell_type"] == "markdown" and "you will" in first, (
        f"{nb_path.name}: the first cell must say what the learner will be able to do"
    )
    headings = [_source(c).lower() for c in cells if c["cell_type"] == "markdown"]
    assert any(h.lstrip().startswith("## summary") for h in headings), f"{nb_path.name}: no '## Summary' section"
    assert any(h.lstrip().startswith("## exercises") for h in headings), f"{nb_path.name}: no '## Exercises' section"
    code = "\n".join(_source(c) for c in cells if c["cell_type"] == "code")
    assert "sys.path" not in code, f"{nb_path.name}: import cuboidlib as an installed package, not via sys.path"
    for folder in re.findall(r"addsitedir\((.*)\)", code):  # only the experiment scripts, which are not a package
        assert "experiments" in folder, f"{nb_path.name}: addsitedir({folder}) may add only experiments/"
    checked = [c for c in cells if "nbval-check-output" in c.get("metadata", {}).get("tags", [])]
    assert checked, f"{nb_path.name}: no cell is tagged nbval-check-output, so nbval checks no printed output"
    assert "NBVAL_" not in code, f"{nb_path.name}: mark checked cells with the nbval-check-output tag, not a comment"
    assert re.search(r"^\s*assert ", code, re.M), f"{nb_path.name}: the lesson's claims are not checked by asserts"


def _exercise_numbers(text: str) -> list[int]:
    return [int(n) for n in re.findall(r"^(\d+)\. ", text, re.M)]


@pytest.mark.parametrize("solutions", SOLUTIONS, ids=lambda p: p.name)
def test_every_exercise_of_a_lesson_has_a_solution_that_states_its_cost(solutions):
    lesson = ROOT / "notebooks" / solutions.name.replace("_solutions", "")
    assert lesson.is_file(), f"{solutions.name}: no lesson {lesson.name}"
    exercises = next(_source(c) for c in _cells(lesson) if _source(c).lstrip().lower().startswith("## exercises"))
    numbers = _exercise_numbers(exercises)
    assert numbers == list(range(1, len(numbers) + 1)) and numbers, f"{lesson.name}: exercises are not numbered 1, 2, ..."
    assert f"solutions/{solutions.name}" in exercises, f"{lesson.name}: the exercises do not link {solutions.name}"
    costs = re.findall(r"\((?:about |under )?\d+(?:\.\d+)?(?:-\d+)? ?(?:s|seconds?|min|minutes?)\)", exercises)
    assert len(costs) >= len(numbers), f"{lesson.name}: every exercise states its cost in brackets (found {costs})"
    cells = [_source(c) for c in _cells(solutions)]
    for n in numbers:
        heads = [i for i, text in enumerate(cells) if text.startswith(f"## Exercise {n}:")]
        assert len(heads) == 1, f"{solutions.name}: no single '## Exercise {n}:' section"
        assert re.search(r"\*Cost: [^*]*(second|s|minute|min)[^*]*\*", cells[heads[0]]), (
            f"{solutions.name}: exercise {n} does not state its cost")
        code = next((text for text in cells[heads[0] + 1:] if not text.startswith("## ")), "")
        assert code, f"{solutions.name}: exercise {n} has no solution"
    code = "\n".join(_source(c) for c in _cells(solutions) if c["cell_type"] == "code")
    assert re.search(r"^\s*assert ", code, re.M), f"{solutions.name}: the answers' claims are not checked by asserts"


@pytest.mark.parametrize("nb_path", NOTEBOOKS + SOLUTIONS, ids=lambda p: p.name)
def test_notebook_names_the_installed_kernel_as_jupyterlab_does(nb_path):
    # ipykernel installs the kernel "python3" with the display name "Python 3 (ipykernel)"; a notebook that
    # stores another name is marked as changed when JupyterLab opens it, and a save leaves a diff
    from jupyter_client.kernelspec import KernelSpecManager

    spec = KernelSpecManager().get_kernel_spec("python3")
    stored = json.loads(nb_path.read_text())["metadata"]["kernelspec"]
    assert stored == {"display_name": spec.display_name, "language": spec.language, "name": "python3"}, (
        f"{nb_path.name}: kernelspec {stored} differs from the installed kernel's")


@pytest.mark.parametrize("nb_path", NOTEBOOKS + SOLUTIONS, ids=lambda p: p.name)
def test_notebook_lines_read_without_scrolling(nb_path):
    cells = json.loads(nb_path.read_text())["cells"]
    long = [(i, len(line)) for i, c in enumerate(cells) for line in _source(c).split("\n") if len(line) > 200]
    assert not long, f"{nb_path.name}: (cell, length) of lines over 200 characters: {long}"


@pytest.mark.parametrize("nb_path", NOTEBOOKS + SOLUTIONS, ids=lambda p: p.name)
def test_notebook_stays_small(nb_path):
    assert nb_path.stat().st_size < 5 * 2**20, f"{nb_path.name} is larger than 5 MiB"


# ----------------------------------------------------------------------------------------------
# The committed checkpoints
# ----------------------------------------------------------------------------------------------

CHECKPOINTS = ROOT / "data_samples" / "checkpoints"
CATEGORIES = ("chair", "table", "airplane", "animal")
PAPER_M = {"chair": 16, "table": 14, "airplane": 20, "animal": 16}


@pytest.mark.parametrize("category", CATEGORIES)
def test_committed_checkpoint_comes_with_its_card_and_config(category):
    from cuboidlib.checkpoint import load_checkpoint
    from cuboidlib.release import read_card
    from cuboidlib.train_config import TrainConfig

    path = CHECKPOINTS / f"{category}.pt"
    state = load_checkpoint(path)  # weights_only: nothing in the file can run code
    assert "optimizer" not in state, "a released checkpoint holds weights and config only"
    card = read_card(path)
    config = TrainConfig.from_dict(card["config"])
    assert card["config"] == state["config"] and config.category == category
    assert config.model_config.num_cuboids == PAPER_M[category]
    # two stages: the recipe (configs/<category>.json), then the fine-tuning of configs/finetune/<category>.json,
    # which starts from the first stage's best weights; one command (--finetune, one process or two under
    # torchrun; --resume when it continued a finished first stage), or, for a network released before that
    # command existed, the second of two commands
    configs = "data_samples/checkpoints/configs"
    one_command = rf"(torchrun --nproc_per_node=2 -m )?cuboidlib train --config {configs}/{category}\.json " \
                  rf"--finetune {configs}/finetune/{category}\.json --out runs/{category} " \
                  rf"--release data_samples/checkpoints/{category}\.pt( --resume)?( --quiet)?"
    second_of_two = rf"cuboidlib train --config {configs}/finetune/{category}\.json --out \S+ " \
                    rf"--release data_samples/checkpoints/{category}\.pt"
    assert re.fullmatch(one_command, card["command"]) or re.fullmatch(second_of_two, card["command"]), card["command"]
    if card["command"].startswith("torchrun"):
        assert card["machine"]["processes"] == 2, "the card records both training processes"
    assert TrainConfig.load_json(CHECKPOINTS / "configs" / "finetune" / f"{category}.json") == config
    first = card["initialised_from"]
    assert config.init_from == first["checkpoint"] == f"runs/{category}/best.pt"
    assert TrainConfig.load_json(CHECKPOINTS / "configs" / f"{category}.json") == TrainConfig.from_dict(first["config"])
    seconds = first["training"]["seconds"] + card["training"]["seconds"]
    assert seconds <= 60 * 60, "each checkpoint trains in at most 60 minutes, both stages together"
    assert card["test"]["n_shapes"] >= 200, "scored on a test split of at least 200 shapes"
    curve = card["training"]["validation"]
    assert curve and all("miou" in e and "n_ac" in e for e in curve), "the card holds the validation curve"
    assert card["test"]["split"] == "test"


def test_every_network_and_config_ships_in_the_package():
    """pyproject's package data for cuboidlib.networks covers every network, card and config file."""
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    shipped = {path for pattern in patterns["cuboidlib.networks"] for path in CHECKPOINTS.glob(pattern)}
    committed = {path for suffix in ("*.pt", "*.json") for path in CHECKPOINTS.rglob(suffix)}
    assert committed and committed <= shipped, sorted(str(p.relative_to(CHECKPOINTS)) for p in committed - shipped)


@pytest.mark.parametrize("stage", ["", "finetune/"])
def test_paper_scale_config_is_the_chair_recipe_at_the_papers_scale(stage):
    """configs/paper_scale/ (data_samples/checkpoints/README.md, "At paper scale, on a GPU") changes only the scale
    of the chair recipe."""
    from cuboidlib.dataset import split_indices
    from cuboidlib.model import ModelConfig
    from cuboidlib.train_config import TrainConfig

    recipe = TrainConfig.load_json(CHECKPOINTS / "configs" / f"{stage}chair.json")
    large = TrainConfig.load_json(CHECKPOINTS / "configs" / "paper_scale" / f"{stage}chair.json")
    paper = ModelConfig()
    sizes = ("k", "edge_dims", "global_dim", "latent_dim", "cuboid_code_dim", "cuboid_feature_dims",
             "exist_hidden_dim", "seg_dim")
    assert all(getattr(large.model_config, name) == getattr(paper, name) for name in sizes), "the paper's network"
    assert large.n_points == 4096 and large.batch_size == 32 and large.n_shapes >= 1000
    assert len(split_indices(large.n_shapes, large.split_fractions, large.split_seed)["test"]) >= 200
    assert large.loss_config.existence_min_points == 24, "0.6 % of 4096 points, the authors' own target"
    scale = {"n_shapes", "n_points", "split_fractions", "batch_size", "max_minutes", "num_threads", "init_from"}
    changed = {key for key, value in large.to_dict().items() if value != recipe.to_dict()[key]}
    assert changed - {"model", "loss"} <= scale
    switches = {key: value for key, value in recipe.model.items() if key not in sizes}
    assert {key: large.model[key] for key in switches} == switches, "the recipe's switches, on the paper's sizes"
    assert {**large.loss, "existence_min_points": None} == {**recipe.loss, "existence_min_points": None}
    if stage:
        assert large.init_from == "runs/chair_large/best.pt"


def test_the_15_minute_page_shows_the_cards_of_its_networks():
    """experiments/fifteen/README.md, "The runs": the recipe's four networks, each row read from its card in
    experiments/fifteen/results/ (the command's minutes, the steps of both stages, mIoU, N_AC, the weakest part,
    the Chamfer distance and its ratio to k-means boxes, the box distance)."""
    from cuboidlib.release import read_card

    text = (ROOT / "experiments" / "fifteen" / "README.md").read_text()
    section = text[text.index("**The recipe's networks, on a quiet machine**"):]
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in section[:section.index("\n\n", section.index("| category"))].splitlines() if line.startswith("| ")}
    for category in CATEGORIES:
        card = read_card(ROOT / "experiments" / "fifteen" / "results" / f"{category}_15min.pt")
        network, baseline = card["test"]["results"]
        cd = [1000 * r["chamfer"][0]["value"] for r in (network, baseline)]
        weakest = min(network["part_iou"], key=network["part_iou"].get)
        expected = [f"{card['command_seconds'] / 60:.1f}",
                    f"{card['initialised_from']['training']['steps']} + {card['training']['steps']}",
                    f"{100 * network['miou']:.1f}", f"{network['n_ac']:.1f}",
                    f"{weakest} {100 * network['part_iou'][weakest]:.1f}", f"{cd[0]:.2f} ({cd[1] / cd[0]:.1f}x)",
                    f"{network['box_distance']:.4f}"]
        _, minutes, steps, miou, n_ac, part, chamfer, box = rows[category]
        shown = [minutes, steps, miou.split(" (")[0], n_ac.split(" (")[0], part, chamfer, box]
        assert shown == expected, (category, shown, expected)


@pytest.mark.parametrize("page, short", [("README.md", True), ("data_samples/checkpoints/README.md", False)])
def test_checkpoint_tables_are_the_cards(page, short):
    from cuboidlib.release import cards_markdown

    text = (ROOT / page).read_text()
    block = re.search(r"<!-- checkpoints:start -->\n(.*?)\n<!-- checkpoints:end -->", text, re.S)
    assert block, f"{page} misses the checkpoint table markers"
    expected = cards_markdown([CHECKPOINTS / f"{c}.pt" for c in CATEGORIES], short=short)
    assert block.group(1).strip() == expected, f"regenerate {page}'s table with cuboidlib.release.cards_markdown"


# ----------------------------------------------------------------------------------------------
# Layout
# ----------------------------------------------------------------------------------------------


def _code_lines(node) -> int:
    """Lines of a function without its docstring."""
    import ast

    first = node.body[0]
    doc = first.end_lineno - first.lineno + 1 if (
        isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str)
    ) else 0
    return node.end_lineno - node.lineno + 1 - doc


@pytest.mark.parametrize("folder", ["cuboidlib", "experiments", "benchmarks", "docs"])
def test_functions_stay_short(folder):
    import ast

    long = []
    for path in sorted((ROOT / folder).glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and _code_lines(node) > 80:
                long.append(f"{path.name}:{node.name} ({_code_lines(node)} lines)")
    assert not long, f"functions over 80 lines of code (docstring excluded): {long}"


def _flat(d: dict, prefix: str = "") -> dict:
    """A config dict with its model and loss sections flattened to "model.k", "loss.lambda_compact", ..."""
    out = {}
    for key, value in d.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _script_module(path: Path):
    """A script of experiments/ imported as a module (its main() is not run), with its folder on the import path
    while it loads, as when it runs: a script may import a sibling script."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(path.parent))
    return module


def test_the_second_stage_runs_name_what_they_change_and_the_page_shows_them():
    """experiments/fifteen/results/second_stage/<first stage>--<name>.json: the cards named "recipe" trained the
    recipe's second stage and no other did; each began from a first stage kept in results/first_stage/; and
    experiments/fifteen/README.md shows the table that second_stage_table.py makes of them."""
    fifteen = ROOT / "experiments" / "fifteen"
    table = _script_module(fifteen / "second_stage_table.py")
    cards = sorted((fifteen / "results" / "second_stage").glob("*.json"))
    assert len(cards) >= 2
    for path in cards:
        first, name = path.stem.split("--")
        changed = table.changed_settings(json.loads(path.read_text())["config"])
        assert (changed == "the recipe") == (name == "recipe"), (path.name, changed)
        assert (fifteen / "results" / "first_stage" / f"{first}.pt").is_file(), path.name
    block = re.search(r"<!-- second-stage:start -->\n(.*?)\n<!-- second-stage:end -->",
                      (fifteen / "README.md").read_text(), re.S)
    assert block is not None
    assert block.group(1).strip() == "\n".join([table.HEADER, table.RULE] + [table.row(c) for c in cards])


def test_the_seed_runs_train_the_recipe_and_the_page_shows_them():
    """experiments/fifteen/results/seeds/<category>--<name>--seed<seed>.json: each first stage is the recipe's but for
    its seed, step budget and threads, its learning rate (falling over the steps instead of the minutes, or
    constant, with or without a warm-up), its existence weight and its compactness weight, which the second stage
    shares or keeps at the recipe's (then the table names the first stage's). The step budget is seeds.sh's 2500
    unless the name ends in another ("-1900steps"). The page shows the table that seeds_table.py makes of them."""
    from cuboidlib.train_config import TrainConfig

    fifteen = ROOT / "experiments" / "fifteen"
    table = _script_module(fifteen / "seeds_table.py")
    cards = sorted((fifteen / "results" / "seeds").glob("*.json"))
    assert len(cards) >= 2
    for path in cards:
        category, name, seed = path.stem.split("--")
        card = json.loads(path.read_text())
        first = _flat(card["initialised_from"]["config"])
        recipe = _flat(TrainConfig.load_json(CHECKPOINTS / "configs" / "15min" / f"{category}.json").to_dict())
        differ = {k for k, v in first.items() if v != recipe[k]}
        allowed = {"seed", "max_steps", "max_minutes", "num_threads", "lr_schedule", "lr_warmup_steps",
                   "loss.lambda_compact", "loss.lambda_exist"}
        assert differ <= allowed and first["seed"] == int(seed.removeprefix("seed")), (path.name, differ)
        second = _flat(card["config"])  # seeds.sh --both: one weight in both stages
        recipe_second = _flat(TrainConfig.load_json(CHECKPOINTS / "configs" / "15min" / "finetune" / f"{category}.json")
                              .to_dict())
        lambda_1 = first["loss.lambda_compact"]
        assert second["loss.lambda_compact"] in (lambda_1, recipe_second["loss.lambda_compact"]), path.name
        only_first = second["loss.lambda_compact"] != lambda_1  # seeds.sh --set: the first stage's alone
        assert (f"first-stage lambda_1 {lambda_1:g}" in table.other_changes(
            card["initialised_from"]["config"], second["loss.lambda_compact"])) == only_first
        over_steps = "cosine" if recipe["lr_schedule"] == "cosine_minutes" else recipe["lr_schedule"]
        assert first["lr_schedule"] == ("constant" if name == "constant" else over_steps), path.name
        steps = re.search(r"-(\d+)steps$", name)  # e.g. "falling-1900steps"; else seeds.sh's 2500
        assert first["max_steps"] == (int(steps.group(1)) if steps else 2500), path.name
    block = re.search(r"<!-- seeds:start -->\n(.*?)\n<!-- seeds:end -->", (fifteen / "README.md").read_text(), re.S)
    assert block is not None
    assert block.group(1).strip() == "\n".join(table.table(cards))


def test_the_tail_table_comes_from_tail_cuboids_and_the_page_shows_it():
    """experiments/fifteen/results/tail_cuboids.json: rows of tail_cuboids.py for networks kept in the repository,
    a short- and a long-tail row each; the page shows the table the script makes of them."""
    fifteen = ROOT / "experiments" / "fifteen"
    script = _script_module(fifteen / "tail_cuboids.py")
    rows = json.loads((fifteen / "results" / "tail_cuboids.json").read_text())["rows"]
    assert [r["kind"] for r in rows] == ["short", "long"] * (len(rows) // 2) and rows
    for r in rows:
        assert (ROOT / r["network"]).is_file(), r["network"]
        assert 0 <= r["with_tail_cuboid"] <= r["animals"] and 0 <= r["named_tail_percent"] <= 100
    block = re.search(r"<!-- tails:start -->\n(.*?)\n<!-- tails:end -->", (fifteen / "README.md").read_text(), re.S)
    assert block is not None
    assert block.group(1).strip() == "\n".join(script.table(rows))


def test_the_worst_fitted_table_comes_from_worst_fitted_and_the_page_shows_it():
    """experiments/fifteen/results/worst_fitted.json: rows of worst_fitted.py for networks kept in the repository;
    each K's part shares add up to 100 %, and the page shows the table the script makes of them."""
    fifteen = ROOT / "experiments" / "fifteen"
    script = _script_module(fifteen / "worst_fitted.py")
    rows = json.loads((fifteen / "results" / "worst_fitted.json").read_text())["rows"]
    assert rows
    for r in rows:
        assert (ROOT / r["network"]).is_file(), r["network"]
        shares = [r[f"{part}_share_of_worst_percent"] for part in script.PARTS]
        assert sum(shares) == pytest.approx(100) and 0 <= r["tail_points_among_worst_percent"] <= 100
    block = re.search(r"<!-- worst:start -->\n(.*?)\n<!-- worst:end -->", (fifteen / "README.md").read_text(), re.S)
    assert block is not None
    assert block.group(1).strip() == "\n".join(script.table(rows))


@pytest.mark.parametrize("stage", ["", "finetune/"])
def test_the_15_minute_recipe_is_one_recipe_with_its_stated_exceptions(stage):
    """configs/15min/: the same settings for every category but M, the compactness weight (the animals' smaller
    in the first stage than in the second), the animals' first-stage existence target and falling learning rate,
    and their longer second stage, each measured in experiments/fifteen/README.md; the first stage is the
    committed first stage with a shorter budget, both cores and, for chairs and tables, a larger compactness
    weight, for animals a smaller one."""
    from cuboidlib.train_config import TrainConfig

    quick = {c: _flat(TrainConfig.load_json(CHECKPOINTS / "configs" / "15min" / f"{stage}{c}.json").to_dict())
             for c in CATEGORIES}
    per_category = {"category", "model.num_cuboids", "init_from"}
    weight = {"loss.lambda_compact"}
    exceptions = {"airplane": weight,
                  "animal": weight | {"max_steps", "max_minutes"} if stage
                  else weight | {"loss.existence_min_points", "lr_schedule", "lr_final"}}
    assert {c: quick[c]["loss.lambda_compact"] for c in CATEGORIES} == {
        "chair": 0.05, "table": 0.05, "airplane": 0.001, "animal": 0.02 if stage else 0.005}
    for category in CATEGORIES:
        differ = {k for k, v in quick[category].items() if v != quick["chair"][k]} - per_category
        assert differ == exceptions.get(category, set()), (category, differ)
    if not stage:
        for category in CATEGORIES:
            committed = _flat(TrainConfig.load_json(CHECKPOINTS / "configs" / f"{category}.json").to_dict())
            differ = {k for k, v in quick[category].items() if v != committed[k]}
            other_weight = {"loss.lambda_compact"} if category in ("chair", "table", "animal") else set()
            falling_rate = {"lr_schedule", "lr_final"} if category == "animal" else set()
            # the committed airplane trains on generator version 2 for a step count; the 15-minute recipe stays on 1
            version_2 = {"generator_version", "max_steps"} if committed["generator_version"] == 2 else set()
            assert differ <= {"max_minutes", "num_threads", "seed"} | other_weight | falling_rate | version_2, \
                (category, differ)
            assert quick[category]["generator_version"] == 1
            assert quick[category]["max_minutes"] < 15 and quick[category]["num_threads"] == "auto"
