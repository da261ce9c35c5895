"""Pictures a person checks, each drawing into an ``ax`` it is given (the figure and the PNG
are the caller's): one module per picture with ``confs`` and a ``main(conf, inputs..., output,
*, overwrite=False, progress=False) -> Path`` that writes it, or, where what it draws must
first be computed by stages, the drawing of a chain's result (the error surfaces: the chain
stages.pipelines.error_surface computes them and writes the picture; a frame's features,
stages.pipelines.frame_points; its belief, stages.pipelines.frame_belief).

- :mod:`.field` the field as every picture draws it; :mod:`.figure` Agg figures, atomic PNGs;
- :mod:`.map` a map's tables; :mod:`.points` a frame's extracted features, on the image and on
  the field; :mod:`.belief` the particle filter's belief of one frame; :mod:`.hypotheses` a
  frame's ranked hypotheses; :mod:`.report_plots` the plots of an evaluation report;
  :mod:`.comparison` a batch's error CDFs per dataset and its summary of every method on
  every dataset; :mod:`.error_surface` the drawing of the SURF template paper's error surfaces
  of the white-point table and of a template, and of the queries' errors against their
  distance from it;
  :mod:`.html_report` one self-contained page of reports and their pictures.

Pictures read the stages' artifacts or draw what a chain computed; none runs a stage, and no
stage imports them."""

import logging

log = logging.getLogger(__name__)

# matplotlib's warnings about its own caches, which cost a picture nothing: a config folder it
# cannot make or write (HOME or MPLCONFIGDIR read-only or full: it works in a temporary one,
# then says so in 400 characters) and a font cache it cannot save. Said under -v, as
# fieldloc's INFO.
# (the beginnings of their messages' templates, before the paths are put in)
_MPL_CACHE_NOTES = ("mkdir -p failed for path %s", "%s is not a writable directory",
                    "Matplotlib created a temporary cache directory",
                    "Could not save font_manager cache")


def _cache_note(record: logging.LogRecord) -> bool:
    """A filter on matplotlib's loggers: a note of ``_MPL_CACHE_NOTES`` goes to our INFO log
    (in one short line) instead of the terminal as a WARNING; every other record passes."""
    if isinstance(record.msg, str) and record.msg.startswith(_MPL_CACHE_NOTES):
        log.info("matplotlib: %s", record.getMessage()[:200])
        return False
    return True


# before matplotlib is imported (each picture module imports it below this package), so that
# the note of its import is filtered too
for _name in ("matplotlib", "matplotlib.font_manager"):
    logging.getLogger(_name).addFilter(_cache_note)
