"""Table 4 of the paper: robustness of the point-to-cuboid distance to input noise (Sec. 4.3).

Chairs, trained and tested on noisy inputs: Gaussian noise of standard deviation sigma_n in
{0, 0.01, 0.02, 0.03} is added to the positions of every shape (train, validation and test
splits, drawn once, seeded; the normals stay those of the clean surface; shapes have a bounding
box diagonal of 1). Four reconstruction distances:

* "Distance": the nearest-surface distance, which ignores normals (``distance="nearest_surface"``);
* "Normal" with sigma_s = 0, 0.025 and 0.05: the paper's Eq. (5), projecting along the normal
  onto the face that matches it, after a random step of standard deviation sigma_s.

Scores: Chamfer distance and normal consistency of the cuboids against the (noisy) input points,
as the paper describes, and against the clean test shapes (how well the shape is recovered
despite the noise).
"""

from __future__ import annotations

import argparse

import command_line
import runner

NOISE = (0.0, 0.01, 0.02, 0.03)
#: (column name, distance, sigma_s)
COLUMNS = (("Distance", "nearest_surface", 0.0), ("Normal", "normal", 0.0), ("Normal", "normal", 0.025),
           ("Normal", "normal", 0.05))
#: Table 4 of Yang & Chen (2021): (CD, NC) per sigma_n and column (chairs).
PAPER = {
    "source": "Table 4 of Yang & Chen, SIGGRAPH 2021 (chairs; Chamfer distance in an undocumented convention, "
              "normal consistency)",
    "cd_nc": {
        0.0: {("Distance", 0.0): (56.042, 0.451), ("Normal", 0.0): (0.386, 0.758), ("Normal", 0.025): (0.389, 0.762),
              ("Normal", 0.05): (0.399, 0.763)},
        0.01: {("Distance", 0.0): (57.371, 0.448), ("Normal", 0.0): (0.463, 0.732), ("Normal", 0.025): (0.480, 0.730),
               ("Normal", 0.05): (0.442, 0.736)},
        0.02: {("Distance", 0.0): (57.450, 0.465), ("Normal", 0.0): (0.626, 0.667), ("Normal", 0.025): (0.598, 0.679),
               ("Normal", 0.05): (0.572, 0.671)},
        0.03: {("Distance", 0.0): (58.734, 0.461), ("Normal", 0.0): (0.909, 0.641), ("Normal", 0.025): (0.727, 0.645),
               ("Normal", 0.05): (0.754, 0.652)},
    },
}


def column_name(column: str, sigma_s: float) -> str:
    """A column's name on the command line: Distance, Normal-0, Normal-0.025, Normal-0.05."""
    return column if column == "Distance" else f"{column}-{sigma_s:g}"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--noise", type=command_line.float_list_option(NOISE), default=NOISE,
                   help="comma-separated subset of the noise levels sigma_n " + ",".join(map(str, NOISE)) + " (default: all)")
    names = [column_name(c, s) for c, _, s in COLUMNS]
    p.add_argument("--columns", type=command_line.categories_option(tuple(names)), default=tuple(names),
                   help="comma-separated subset of the columns " + ",".join(names) + " (default: all)")


def build_runs(scale: runner.Scale, args: argparse.Namespace) -> list[runner.Run]:
    runs = []
    noise, columns = getattr(args, "noise", NOISE), getattr(args, "columns", None)  # Fig. 9 passes its own args
    for sigma_n in noise:
        for column, distance, sigma_s in COLUMNS:
            if columns is not None and column_name(column, sigma_s) not in columns:
                continue
            for seed in scale.seeds:
                loss = {"loss": {"distance": distance, "sigma_s": sigma_s}}
                config = scale.config("chair", seed, **loss)
                key = {"sigma_n": sigma_n, "distance": column, "sigma_s": sigma_s, "seed": seed}
                runs.append(runner.Run(f"noise{sigma_n:g}_{column}_s{sigma_s:g}_seed{seed}", key, config,
                                       options={"sigma_n": sigma_n}, finetune=scale.finetune_config("chair", seed, **loss)))
    return runs


def _json_paper() -> dict:
    return {"source": PAPER["source"],
            "cd_nc": {str(n): {f"{c} sigma_s={s}": v for (c, s), v in cells.items()} for n, cells in PAPER["cd_nc"].items()}}


def report(records: list[dict], scale: runner.Scale, args: argparse.Namespace) -> tuple[list[dict], str]:
    metrics = ("cd", "nc", "nc_both", "cd_clean", "nc_clean", "nc_both_clean", "miou", "n_ac")
    summary = runner.summarize(runner.result_rows(records), ("sigma_n", "distance", "sigma_s"), metrics)
    rows = []
    for row in summary:
        row["paper_cd"], row["paper_nc"] = PAPER["cd_nc"][row["sigma_n"]][row["distance"], row["sigma_s"]]
        rows.append([f"{row['sigma_n']:.2f}", row["distance"], f"{row['sigma_s']:.3f}",
                     runner.mean_sd(row, "cd", 1000), runner.mean_sd(row, "cd_clean", 1000),
                     runner.paper_value(row["paper_cd"]), runner.mean_sd(row, "nc_both"),
                     runner.mean_sd(row, "nc_both_clean"), runner.mean_sd(row, "nc"),
                     runner.paper_value(row["paper_nc"]), runner.mean_sd(row, "n_ac", 1, 2)])
    headers = ["sigma_n", "distance", "sigma_s", "CD x1000 input", "CD x1000 clean", "CD (paper)", "NC input",
               "NC clean", "NC input, from points", "NC (paper)", "N_AC"]
    return summary, "\n".join([
        "Table 4: point-to-cuboid distance under input noise (chairs)", runner.text_table(headers, rows),
        runner.CD_CONVENTION,
        "input: against the noisy test points the network saw (the paper's wording); clean: against the same test "
        "shapes without noise. NC: normal consistency both ways, the mean of |n . n'| from every input point to the "
        "nearest of 4096 points sampled on the cuboids and from every sample to its nearest input point (1 = perfect); "
        "'from points' is the first direction alone.",
        f"Paper numbers: {PAPER['source']}.",
    ])


def notes(scale: runner.Scale, args: argparse.Namespace) -> list[str]:
    return ["Noise: x + sigma_n e, e ~ N(0, I_3) per point (runner.add_noise), drawn once per split from seeds derived "
            "from the data seed, the same draw scaled for every sigma_n; normals unchanged; the model sees noisy "
            "training, validation and test points. Shapes are normalised to a bounding-box diagonal of 1."]


EXPERIMENT = command_line.Experiment(
    name="table4_distance",
    title="Table 4: nearest-surface vs normal-aware distance (sigma_s 0, 0.025, 0.05) under input noise "
          "sigma_n 0-0.03 (chairs; Chamfer distance, normal consistency)",
    description=__doc__,
    paper=_json_paper(),
    default_steps=600,
    default_seeds=1,
    build_runs=build_runs,
    report=report,
    add_arguments=add_arguments,
    notes=notes,
    recipes=("course", runner.FIFTEEN_MINUTES),
)

if __name__ == "__main__":
    raise SystemExit(command_line.main(EXPERIMENT))
