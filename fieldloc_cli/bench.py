"""`fieldloc bench`: speed of each stage against its goal and its in-process baseline."""

from __future__ import annotations

from pathlib import Path

import click

from .common import FilePath, WholeNumber


@click.command("bench")
@click.option("--only", multiple=True, metavar="NAME",
              help="Run rows whose name contains NAME (repeatable; --list names the rows).")
@click.option("--list", "list_rows", is_flag=True, help="Print the rows' names and exit.")
@click.option("--repeat", type=WholeNumber(min=1), default=5, show_default=True,
              help="Timed runs per row (medians are reported).")
@click.option("--json", "json_path", type=FilePath(dir_okay=False, path_type=Path),
              help="Also write the rows as JSON.")
@click.option("--overwrite", is_flag=True, help="Replace an existing --json file.")
@click.option("--format", "fmt", type=click.Choice(["text", "markdown"]), default="text",
              show_default=True, help="Table format (markdown: docs/results.md's table).")
@click.option("--from-json", "from_json", multiple=True,
              type=FilePath(dir_okay=False, path_type=Path),
              help="Print the table of a saved --json run instead of timing again (repeatable: "
                   "a later run's rows replace the earlier's of the same name; with --json, "
                   "the merged rows are written).")
@click.pass_context
def bench(ctx, only, list_rows, repeat, json_path, overwrite, fmt, from_json):
    """Time the stages on generated inputs and print a table."""
    from stages.pipelines import bench as stage
    from stages.pipelines.bench import harness

    if list_rows:
        click.echo("\n".join(stage.ROWS))
        return
    quiet = (ctx.find_root().obj or {}).get("quiet")
    show = harness.format_markdown if fmt == "markdown" else harness.format_table
    if json_path:
        from stages.common.artifacts import check_output

        check_output(json_path, {"--from-json": from_json},  # before minutes of timing
                     overwrite=overwrite)
    if from_json:
        rows = harness.merge_runs([harness.read_json(p) for p in from_json])
        click.echo(show(rows), nl=fmt != "markdown")
        if json_path:
            harness.write_json(rows, json_path)
        return

    def progress(name):
        if not quiet:
            click.echo(f"bench: {name} ...", err=True)

    rows = stage.run(list(only) or None, repeat=repeat, progress=progress)
    click.echo(show(rows), nl=fmt != "markdown")
    if json_path:
        harness.write_json(rows, json_path)
