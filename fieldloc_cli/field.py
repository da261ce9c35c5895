"""`fieldloc field import FILE [--format F] -o field.yaml`: a team's field file (B-Human,
bit-bots, Falcons, MINHO, Carpe Noctem, CAMBADA, HULKs) as a fieldloc field YAML."""

from __future__ import annotations

import click

from stages.common.one_line import one_line

from .common import FilePath, summary
from .lazy_group import outputs_complete
from .stage_defaults import FIELD_FORMATS


@click.group()
def field():
    """Field definitions: import a team's own field file."""


@field.command("import")
@click.argument("path", type=FilePath(dir_okay=False))
@click.option("--format", "fmt", default=None, type=click.Choice(FIELD_FORMATS),
              help="bhuman: fieldDimensions.cfg (mm); bitbots: map generator config (cm) or"
                   " config.yaml (m); falcons: multiCam.yaml or an MSL letters list (m);"
                   " minho: .view (mm); carpenoctem: FootballField.conf (mm); cambada: field"
                   " JSON (mm); hulks: field_dimensions JSON/JSON5 (m)"
                   " [default: told from the file's name and content].")
@click.option("-o", "--output", required=True, type=FilePath(dir_okay=False),
              help="Field YAML to write.")
@click.option("--venue", help="falcons multiCam.yaml: the venue block (DeLocht for"
                              " dimensionsDeLocht) [default: the one global.dimensions names].")
@click.option("--section", help="carpenoctem FootballField.conf: the field section (Lab,"
                                " Official, ...) [default: the one CurrentField names].")
@click.option("--base", metavar="FIELD",
              help="Preset or field YAML giving the dimensions the team file lacks.")
@click.option("--name", help="Field name [default: FORMAT-FILE or FORMAT-VENUE].")
@click.option("--overwrite", is_flag=True, help="Replace OUTPUT if it exists.")
@click.pass_context
def field_import(ctx, path, fmt, output, venue, section, base, name, overwrite):
    """Read a team's field file and write it as a fieldloc field YAML (metres, between line
    centre lines). Keys of the team file that describe no line and keys this importer does not
    know are kept in the YAML's `imported` record and listed here.

    \b
    Examples:
      fieldloc field import fieldDimensions.cfg --format bhuman -o spl-hall.yaml
      fieldloc field import multiCam.yaml --format falcons --venue DeLocht -o delocht.yaml
      fieldloc field import config.yaml --format bitbots --base kidsize -o lab.yaml
      fieldloc field import Lar.view -o minho-lab.yaml
      fieldloc field import FootballField.conf --section Lab --base msl-2015 -o cnc-lab.yaml
    """
    from stages.common.field import load_field
    from stages.ingest.team_fields import main

    out = main(None, path, output, fmt=fmt, venue=venue, section=section, base=base, name=name,
               overwrite=overwrite)
    outputs_complete(ctx)
    fm = load_field(out)
    rec = fm.spec.get("imported", {})
    summary(ctx, f"wrote {out}: {fm.name}, {fm.length:g} x {fm.width:g} m between line centres,"
               f" lines {fm.line_width:g} m, border {fm.border:g} m; {len(fm.segments)} lines,"
               f" {len(fm.arcs)} arcs")
    if rec.get("from_base"):
        summary(ctx, f"from {rec['from_base']['field']}: {', '.join(rec['from_base']['keys'])}")
    for note in rec.get("notes", []):
        click.echo(one_line(f"note: {note}"), err=True)  # what the import could not carry over
    if rec.get("field_lines_check"):
        click.echo(one_line(f"check: {rec['field_lines_check']}"), err=True)
    unknown = rec.get("unknown") or {}
    if unknown:
        click.echo(one_line(f"unknown keys ({len(unknown)}, kept under imported.unknown): "
                            + ", ".join(f"{k}={v}" for k, v in unknown.items())), err=True)
