"""The ``cuboidlib`` command-line tool: every subcommand and option in one place.

The parser and the error rule live here, with the commands on shapes (fit, abstract) and on a network's latent
space (generate, interpolate, view). The network commands (samples, train, evaluate) are :mod:`cuboidlib.cli_train`.
What the handlers share (errors, argument types, the inputs, the one rule for outputs) is :mod:`cuboidlib.cli_common`;
the runs over shapes of ``fit`` and ``abstract`` are :mod:`cuboidlib.cli_shapes`.

Each subcommand is a ``_add_*_command`` (its options) and a ``_cmd_*`` handler, a thin layer over the
library. Every handler checks its sizes, seeds and outputs before any work (:func:`cuboidlib.cli_common.check_sizes`,
:func:`cuboidlib.cli_common.check_outputs`). Errors a user can fix are printed as one line with a non-zero exit
code (``--traceback``: the full traceback). The handlers import the library inside, as marked: it imports torch
(seconds), which --help, --version and usage errors do without.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
import warnings
from pathlib import Path

from . import __version__
from .cli_common import (BAR_DELAY, SUMMARY_FILE, Recording, UserError, bars, check_input, check_out_dir,
                         check_sizes, growth_type, load_network, load_shape, mesh_formats_type, model_points,
                         non_negative_int, part_names_type, positive_int, record, resolved_model, threshold_type)
from .cli_shapes import run_shapes
from .cli_train import add_evaluate_command, add_samples_command, add_train_command, resume_note
from .files import MESH_FORMATS


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (plus where to find help), exit code 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")



def build_parser() -> argparse.ArgumentParser:
    """The parser of the ``cuboidlib`` command line.

    Returns:
        The parser; each subcommand sets ``func``, its handler (args -> exit code).
    """
    parser = _Parser(
        prog="cuboidlib",
        description="Cuboid shape abstraction via joint segmentation (Yang & Chen, SIGGRAPH 2021).",
    )
    parser.add_argument("--version", action="version", version=f"cuboidlib {__version__}")
    parser.add_argument("--traceback", action="store_true", help="show the full traceback on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    add_samples_command(sub)
    add_train_command(sub)
    add_evaluate_command(sub)
    _add_fit_command(sub)
    _add_abstract_command(sub)
    _add_generate_command(sub)
    _add_interpolate_command(sub)
    _add_view_command(sub)
    for command in sub.choices.values():  # --traceback is also accepted after the subcommand
        command.add_argument("--traceback", action="store_true", default=argparse.SUPPRESS,
                             help="show the full traceback on errors")
    return parser


class _FitDefault:
    """A :class:`~cuboidlib.fitting.FitConfig` default: looked up only when --help shows it or the fit runs,
    so building the parser does not import torch."""

    def __init__(self, name: str):
        self.name = name

    def value(self):
        from .fitting import FitConfig  # imports torch: start-up time (only for --help or the fit)

        return getattr(FitConfig(), self.name)

    def __str__(self) -> str:
        return str(self.value())


def _add_output_options(p, what: str) -> None:
    """--out, --mesh-format, --quiet (shared by fit, abstract, generate, interpolate)."""
    p.add_argument("--out", required=True, metavar="DIR", help=f"output folder for {what}")
    p.add_argument("--mesh-format", type=mesh_formats_type, default=("glb",), metavar="FORMATS",
                   help=f"cuboid mesh formats to write, comma-separated: any of {','.join(MESH_FORMATS)} "
                   "(default: glb)")
    p.add_argument("--quiet", action="store_true", help="no progress bars and no messages")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the results of an earlier run in --out (the files its manifest lists)")


def _add_shape_options(p) -> None:
    """Options of the commands that write one shape's result (fit, abstract)."""
    p.add_argument("--seed", type=non_negative_int, default=0,
                   help="seed of the point sampling, the fit and the Chamfer samples (default: 0)")
    p.add_argument("--normalized", action="store_true",
                   help="write in the normalised frame (bounding box centred, diagonal 1) instead of the input's")
    p.add_argument("--up", choices=("x", "y", "z", "-x", "-y", "-z", "auto"),
                   help="the input's up axis (default: y, and abstract warns when another axis fits the network "
                   "much better; many CAD and scan files use z); results are written back in the input's axes. "
                   "auto (abstract only): find the frame in any rotation (the mirror plane, then the network's "
                   "reconstruction, the ground and the flat area; cuboidlib.frames), and say which")
    p.add_argument("--front", choices=("x", "y", "z", "-x", "-y", "-z"),
                   help="the direction the input's front faces (default: z, or -y when --up z)")
    p.add_argument("--part-names", type=part_names_type, metavar="NAMES",
                   help="comma-separated names of the input's part labels (e.g. back,seat,leg,arm), for the JSON")


def _add_model_options(p) -> None:
    p.add_argument("--model", required=True, metavar="CHECKPOINT",
                   help="a checkpoint file, a 'cuboidlib train' run folder (its best.pt) or the name of a "
                   "committed checkpoint (e.g. chair = data_samples/checkpoints/chair.pt)")
    p.add_argument("--threshold", type=threshold_type, default=0.5,
                   help="a cuboid exists when its existence probability exceeds this (default: 0.5)")
    p.add_argument("--device", default="cpu", help="cpu (default), cuda[:i] or auto")


def _add_shape_argument(p) -> None:
    p.add_argument("shape", metavar="SHAPE", nargs="+",
                   help="mesh or point cloud files, folders (every mesh and point cloud directly inside) or quoted "
                   "glob patterns ('scans/*.ply'); several shapes are processed in one run, a file that fails is "
                   f"reported and skipped, and {SUMMARY_FILE} lists every shape")


def _add_fit_command(sub) -> None:
    p = sub.add_parser(
        "fit",
        help="fit cuboids to meshes or point clouds (no network needed)",
        description="Fit M cuboids to each shape by gradient descent on the paper's losses (reconstruction "
        "with the normal-aware distance, Eq. 4-5, and compactness, Eq. 6; cuboidlib.fitting), then keep the "
        "cuboids that cover points. Reads any mesh (.obj .ply .off .stl .glb .gltf, sampled with --points "
        "points) or point cloud (.ply .txt .pts .xyz .npy, normals estimated when missing). Writes "
        "DIR/NAME.json (cuboids, see cuboidlib.export), DIR/NAME.glb (cuboids coloured by index) and "
        "DIR/NAME_segmentation.ply (points coloured and labelled by cuboid), in the input's coordinates.",
    )
    _add_shape_argument(p)
    _add_output_options(p, "NAME.json, NAME.glb and NAME_segmentation.ply per shape")
    p.add_argument("--cuboids", type=positive_int, default=_FitDefault("num_cuboids"), metavar="M",
                   help="cuboid slots; the fit decides how many are used (default: %(default)s)")
    p.add_argument("--steps", type=non_negative_int, default=_FitDefault("steps"),
                   help="Adam steps (default: %(default)s)")
    p.add_argument("--restarts", type=positive_int, default=_FitDefault("restarts"), metavar="R",
                   help="fit R times from different starts and keep the lowest loss (default: %(default)s)")
    p.add_argument("--points", type=positive_int, default=2048, metavar="N",
                   help="points sampled on a mesh, or kept of a larger point cloud (default: 2048)")
    p.add_argument("--count", choices=("chamfer", "portion"), default="chamfer",
                   help="how many cuboids are kept: chamfer (default) splits and merges the fitted cuboids while the "
                        "Chamfer distance falls; portion keeps those holding enough of the points (the paper's rule)")
    _add_shape_options(p)
    p.set_defaults(func=_cmd_fit)


def _cmd_fit(args) -> int:
    from ._checks import (MAX_CUBOIDS, MAX_FIT_STEPS, MAX_RESTARTS, MAX_SEED,  # imports torch: start-up time
                          MAX_SHAPE_POINTS)

    check_sizes(("--cuboids", args.cuboids, MAX_CUBOIDS, 1), ("--steps", args.steps, MAX_FIT_STEPS, 0),
                ("--restarts", args.restarts, MAX_RESTARTS, 1), ("--points", args.points, MAX_SHAPE_POINTS, 1),
                ("--seed", args.seed, MAX_SEED, 0))

    def prepare():
        from .abstraction import abstract  # imports torch: start-up time
        from .fitting import FitConfig  # imports torch: start-up time

        for name in ("cuboids", "steps", "restarts"):
            if isinstance(getattr(args, name), _FitDefault):
                setattr(args, name, getattr(args, name).value())
        config = FitConfig(num_cuboids=args.cuboids, steps=args.steps, restarts=args.restarts, seed=args.seed,
                           count=args.count)

        def one(path: str, progress: bool):
            return abstract(path, None, n_points=args.points, seed=args.seed, fit_config=config,
                            part_names=args.part_names, progress=progress, up=args.up, front=args.front)

        return one

    return run_shapes(args, "fitting", prepare)


def _add_abstract_command(sub) -> None:
    p = sub.add_parser(
        "abstract",
        help="cuboids and segmentation of shapes by a trained network",
        description="Run a trained network (z = mu) on meshes or point clouds: M cuboids with existence "
        "and the point-to-cuboid segmentation (Sec. 3). Same inputs and outputs as 'cuboidlib fit'. The shape "
        "is normalised like the training shapes (bounding box centred, diagonal 1, +y up, facing +z).",
    )
    _add_shape_argument(p)
    _add_model_options(p)
    _add_output_options(p, "NAME.json, NAME.glb and NAME_segmentation.ply per shape")
    p.add_argument("--points", type=positive_int, metavar="N",
                   help="points sampled on a mesh, or kept of a larger point cloud (default: as in training)")
    p.add_argument("--centers", choices=("auto", "predicted", "allocation"), default="auto",
                   help="cuboid centres: the predicted translations, the allocation-weighted centroids of the "
                   "points, or auto = what the network was trained with (default)")
    p.add_argument("--refine", type=non_negative_int, default=0, metavar="STEPS",
                   help="then this many steps of the per-shape fit, started from the network's cuboids and "
                   "allocation: tighter cuboids that keep the network's cuboid slots, and so its parts "
                   "(default 0: the network alone; 100 takes about a second)")
    p.add_argument("--merge", type=growth_type, nargs="?", const=0.25, metavar="GROWTH",
                   help="last merge the cuboids that cut one part into pieces: two merge when the box around both "
                   "is at most GROWTH larger than the two (default 0.25; cuboidlib.merging)")
    _add_shape_options(p)
    p.set_defaults(func=_cmd_abstract)


def _cmd_abstract(args) -> int:
    from ._checks import MAX_FIT_STEPS, MAX_SEED, MAX_SHAPE_POINTS  # imports torch: start-up time

    check_sizes(("--points", args.points, MAX_SHAPE_POINTS, 1), ("--refine", args.refine, MAX_FIT_STEPS, 0),
                ("--seed", args.seed, MAX_SEED, 0))
    checkpoint = resolved_model(args.model)

    def prepare():
        from .abstraction import NetworkFitWarning, OrientationWarning, abstract  # imports torch: start-up time

        warnings.simplefilter("ignore", OrientationWarning)  # cli_shapes prints it, without a source line
        warnings.simplefilter("ignore", NetworkFitWarning)  # cli_shapes prints it too

        def one(path: str, progress: bool):
            return abstract(path, args.model, n_points=args.points, seed=args.seed, threshold=args.threshold,
                            centers=args.centers, part_names=args.part_names, device=args.device, up=args.up,
                            front=args.front, refine=args.refine, progress=progress, check=True, merge=args.merge)

        return one

    return run_shapes(args, "running the network", prepare, inputs=[checkpoint])


def _stems(prefix: str, count: int) -> list[str]:
    width = max(2, len(str(count - 1)))
    return [f"{prefix}_{i:0{width}d}" for i in range(count)]


def _write_decoded(args, decoded, stems: list[str], methods: list[dict], start: float, summary) -> int:
    """The end of generate and interpolate: write every decoded shape (normalised frame, no points) as JSON
    and meshes, then print ``summary()``, the seconds since ``start`` and the files written. Exit code 0."""
    from tqdm import tqdm  # start-up time (a quarter of a second)

    from .abstraction import Abstraction  # imports torch: start-up time

    cuboids = decoded.cuboids.to(device="cpu")
    written = []
    with Recording(args, written) as recording:
        for k in tqdm(range(len(stems)), desc="writing shapes", disable=not bars(args), leave=False,
                      delay=BAR_DELAY):
            one = type(cuboids)(cuboids.centers[k:k + 1], cuboids.quaternions[k:k + 1], cuboids.half_sizes[k:k + 1],
                                cuboids.exists[k:k + 1], validate=False)
            result = Abstraction(one, method=methods[k])
            written += list(result.save(args.out, stems[k], args.mesh_format, normalized=True).values())
            recording.tick()
    record(args, written)
    if not args.quiet:
        print(f"{summary()} | {time.perf_counter() - start:.1f} s")
        print(f"wrote {len(written)} files to {args.out} (see them: cuboidlib view {args.out})")
    return 0


def _add_generate_command(sub) -> None:
    p = sub.add_parser(
        "generate",
        help="new shapes from a trained network: decode z ~ N(0, I) (Fig. 12)",
        description="Shape generation (Sec. 4.4): draw latent codes z ~ N(0, I) and decode each into cuboids "
        "with existence. Writes DIR/generated_XX.json and its meshes in the normalised frame (there is no "
        "input shape); 'cuboidlib view DIR' shows them all.",
    )
    _add_model_options(p)
    _add_output_options(p, "generated_XX.json and generated_XX.glb")
    p.add_argument("--count", type=positive_int, default=8, help="shapes to generate (default: 8)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the latent codes (default: 0)")
    p.set_defaults(func=_cmd_generate)


def _cmd_generate(args) -> int:
    import torch  # start-up time

    from ._checks import MAX_SEED, MAX_SHAPES  # imports torch: start-up time
    from .applications import generate_shapes  # imports torch: start-up time
    from .results import result_files  # imports torch: start-up time

    check_sizes(("--count", args.count, MAX_SHAPES, 1), ("--seed", args.seed, MAX_SEED, 0))
    start = time.perf_counter()
    stems = _stems("generated", args.count)
    check_out_dir(args, [resolved_model(args.model)],
                  [n for s in stems for n in result_files(s, args.mesh_format, False).values()])
    model, _, path = load_network(args.model, args.device)
    decoded = generate_shapes(model, args.count, torch.Generator().manual_seed(args.seed), args.threshold)
    methods = [{"name": "generate", "checkpoint": str(path), "seed": args.seed, "sample": k,
                "threshold": args.threshold} for k in range(args.count)]

    def summary() -> str:
        used = decoded.num_existing().tolist()
        return (f"{args.count} shapes generated | cuboids used: {' '.join(map(str, used))} of "
                f"{decoded.cuboids.num_cuboids}")

    return _write_decoded(args, decoded, stems, methods, start, summary)


def _add_interpolate_command(sub) -> None:
    p = sub.add_parser(
        "interpolate",
        help="interpolate between two shapes in the latent space of a trained network (Fig. 13)",
        description="Shape interpolation (Sec. 4.4): encode both shapes, interpolate their latent means "
        "linearly, decode every step. Prints how smooth the path is: the largest distance any point of an "
        "existing cuboid moves between neighbouring steps (normalised frame, shape diagonal 1) and how many "
        "cuboids appear or disappear. Writes DIR/step_XX.json and meshes in the normalised frame.",
    )
    p.add_argument("shape_a", metavar="SHAPE_A", help="the first shape (mesh or point cloud)")
    p.add_argument("shape_b", metavar="SHAPE_B", help="the last shape (mesh or point cloud)")
    _add_model_options(p)
    _add_output_options(p, "step_XX.json and step_XX.glb")
    p.add_argument("--steps", type=positive_int, default=8, help="shapes along the path, ends included (default: 8)")
    p.add_argument("--points", type=positive_int, metavar="N",
                   help="points sampled on a mesh, or kept of a larger point cloud (default: as in training)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the point sampling (default: 0)")
    p.set_defaults(func=_cmd_interpolate)


def _cmd_interpolate(args) -> int:
    from ._checks import MAX_SEED, MAX_SHAPE_POINTS, MAX_SHAPES  # imports torch: start-up time
    from .applications import interpolate_latents  # imports torch: start-up time
    from .results import result_files  # imports torch: start-up time

    start = time.perf_counter()
    if args.steps < 2:
        raise UserError(f"--steps must be at least 2 (the two ends), got {args.steps}")
    check_sizes(("--steps", args.steps, MAX_SHAPES, 2), ("--points", args.points, MAX_SHAPE_POINTS, 1),
                ("--seed", args.seed, MAX_SEED, 0))
    check_input(args.shape_a)
    check_input(args.shape_b)
    stems = _stems("step", args.steps)
    check_out_dir(args, [args.shape_a, args.shape_b, resolved_model(args.model)],
                  [n for s in stems for n in result_files(s, args.mesh_format, False).values()])
    model, state, path = load_network(args.model, args.device)
    n_points = args.points or model_points(state)
    clouds = [load_shape(shape, n_points, args.seed) for shape in (args.shape_a, args.shape_b)]
    for shape, pc in zip((args.shape_a, args.shape_b), clouds):
        if len(pc) <= model.config.k:
            raise UserError(f"{shape}: has {len(pc)} points; the network needs more than k = {model.config.k}")
    interp = interpolate_latents(model, clouds[0].points, clouds[1].points, args.steps, args.threshold,
                                 clouds[0].normals, clouds[1].normals)
    names = (Path(args.shape_a).name, Path(args.shape_b).name)
    methods = [{"name": "interpolate", "checkpoint": str(path), "from": names[0], "to": names[1], "t": float(t),
                "threshold": args.threshold} for t in interp.t]

    def summary() -> str:
        return (f"{args.steps} steps from {names[0]} to {names[1]} | largest move of an existing cuboid between "
                f"neighbouring steps {interp.max_step_change:.4g} ({interp.evenness:.2f} x the mean step; shape "
                f"diagonal 1) | {int(interp.existence_changes.sum())} cuboid(s) appear or disappear")

    return _write_decoded(args, interp.shapes, stems, methods, start, summary)


def _add_view_command(sub) -> None:
    p = sub.add_parser(
        "view",
        help="a self-contained HTML page of results (opens in any browser, no server)",
        description="Draw a result folder (or one result JSON) written by fit, abstract, generate or "
        "interpolate: the points coloured by cuboid and the translucent cuboids, interactive (plotly). "
        "plotly.js is embedded in the page (about 5 MB), so it opens offline in any browser.",
    )
    p.add_argument("result", metavar="RESULT", help="a result folder or a result .json file")
    p.add_argument("--out", metavar="FILE", help="the HTML file (default: RESULT/view.html)")
    p.add_argument("--max-points", type=positive_int, default=4000,
                   help="points drawn in all (evenly spaced subset; default: 4000)")
    p.add_argument("--quiet", action="store_true", help="no messages")
    p.set_defaults(func=_cmd_view)


def _cmd_view(args) -> int:
    from .export import read_manifest  # imports torch: start-up time
    from .export_view import write_view_html  # imports torch: start-up time

    manifest = read_manifest(args.result) if Path(args.result).is_dir() else None
    if manifest is not None and not manifest.get("complete", True) and not args.quiet:
        print(f"note: the run that wrote {args.result} did not complete ({manifest.get('command')}); "
              "showing what it wrote", file=sys.stderr)
    pages = write_view_html(args.result, args.out, max_points=args.max_points)
    if not args.quiet:
        shown = pages[0] if len(pages) == 1 else f"{pages[0]} and {len(pages) - 1} more page(s) linked from it"
        print(f"wrote {shown} (open it in any browser; plotly.js is embedded, no server or internet needed)")
    return 0


def _missing_package(exc: ImportError) -> int:
    print(f"cuboidlib: error: the package {exc.name or exc} is not installed; install cuboidlib with its "
          "dependencies (README: python -m pip install -e .)", file=sys.stderr)
    return 1


def main(argv: list[str] | None = None) -> int:
    """Run the ``cuboidlib`` command line.

    Args:
        argv: the arguments after ``cuboidlib`` (default: ``sys.argv[1:]``).

    Returns:
        The exit code: 0 success, 1 a shape of several failed or an unexpected error or a missing package,
        2 a user's error (one line on stderr), 3 training diverged, 130 interrupted.
    """
    started = time.time()  # a command's wall time, which train --release records in its card
    parser = build_parser()
    try:  # --help looks up library defaults, which import the dependencies
        args = parser.parse_args(argv)
    except ImportError as exc:
        return _missing_package(exc)
    args.argv, args.started = argv, started
    try:  # a command that writes holds its output folder from its checks to its end (cli_common.hold_folder)
        with contextlib.ExitStack() as args.held:
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"cuboidlib {args.command}: interrupted{resume_note(args)}", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - every error becomes one readable line unless --traceback
        if args.traceback:
            raise
        if isinstance(exc, ImportError):
            return _missing_package(exc)
        message = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, (UserError, ValueError, OSError, FloatingPointError)):
            print(f"cuboidlib {args.command}: error: {message}", file=sys.stderr)
            return 2
        print(f"cuboidlib {args.command}: error: {type(exc).__name__}: {message} "
              "(unexpected; rerun with --traceback for the details)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
