"""`fieldloc evaluate POSES [POSES ...] --truth TRUTH [-o REPORT_DIR]` and
`fieldloc evaluate --table REPORT_DIR ...`: reports per run, one table across runs on stdout."""

from __future__ import annotations

from pathlib import Path

import click

from stages.common.errors import FieldlocError

from .common import FINITE, FilePath, conf_option, overrides_dict, summary
from .lazy_group import RESUMES, outputs_complete, set_resumes
from .stage_defaults import EVALUATE_PRESETS, EVALUATE_STAMP_TOLERANCE


@click.command()
@click.argument("inputs", nargs=-1, required=True, type=FilePath(path_type=Path))
@click.option("--truth", type=FilePath(path_type=Path), default=None,
              help="truth.csv (stamp,x,y,theta) or the dataset folder holding it. Default: the"
              " dataset the poses file names.")
@click.option("-o", "--output", type=FilePath(path_type=Path), default=None,
              help="Report folder (several poses files: one subfolder per file)."
              " Default: <poses>-eval beside each poses file.")
@click.option("--field", default=None,
              help="Field (preset name or YAML) to draw trajectories on; default: the poses"
              " file's field.")
@click.option("--table", "table_only", is_flag=True,
              help="INPUTS are report folders (or report.json files): tabulate them without"
              " recomputing.")
@click.option("--preset", default="default", show_default=True, type=click.Choice(EVALUATE_PRESETS),
              help="Evaluation preset (stages.evaluate.confs).")
@click.option("--stamp-tolerance", type=FINITE, default=None,
              help="Largest stamp difference (s) for a frame to match a truth row"
              f" [default: the preset's; 'default' has {EVALUATE_STAMP_TOLERANCE:g}].")
@click.option("--up-to-mirror", is_flag=True,
              help="Score the pose up to the field's 180 deg symmetry: against the truth or"
              " its mirror, frames accepted up to the mirror counted as accepted.")
@conf_option
@click.option("--format", "fmt", type=click.Choice(["text", "markdown", "csv"]),
              default="text", show_default=True, help="Table format on stdout.")
@click.option("--overwrite", is_flag=True,
              help="Replace fieldloc reports made from other inputs (never a user's files).")
@click.pass_context
def evaluate(ctx, inputs, truth, output, field, table_only, preset, stamp_tolerance,
             up_to_mirror, overrides, fmt, overwrite):
    """Position and heading errors of POSES files (poses.h5) against truth: report.json,
    errors.csv and plots per run, and a table of all runs on stdout.

    Failures count as failures (infinite error). With --table, INPUTS are existing report
    folders and only the table is printed."""
    from stages import evaluate as stage
    from stages.pipelines import evaluation

    if table_only:
        if (truth or output or field or overwrite or stamp_tolerance is not None or overrides
                or up_to_mirror):
            raise FieldlocError("--table only reads existing reports; it takes no --truth, -o,"
                                " --field, --stamp-tolerance, --up-to-mirror, -c or"
                                " --overwrite")
        click.echo(stage.tabulate(list(inputs), fmt=fmt))
        return
    over = overrides_dict(overrides)
    if stamp_tolerance is not None:
        over["stamp_tolerance"] = stamp_tolerance
    if up_to_mirror:
        over["up_to_mirror"] = True
    from stages.common.conf import resolve_conf

    conf = resolve_conf(stage.confs, preset, over)
    outs = stage.report_dirs(list(inputs), output)
    done = []
    for poses, out in zip(inputs, outs):
        # what a stop (a signal, a full disk) leaves: the reports finished before this one
        set_resumes(ctx, RESUMES["evaluate"] if done else None)
        done.append(evaluation.main(conf, poses, truth, out, overwrite=overwrite, field=field))
        # where the report went, above all when no -o chose it (beside the poses file, which
        # may be inside the dataset folder)
        summary(ctx, f"report of {poses} written to {out}"
                + ("" if output is not None else " (beside the poses file; -o to choose)"))
    outputs_complete(ctx)
    click.echo(stage.tabulate(done, fmt=fmt))
    if fmt == "text":
        for out in done:
            click.echo("")
            click.echo(stage.reliability_table(stage.load_report(out)))
