"""A stop (Ctrl-C, SIGTERM) that the command line's signal handler raised where Python drops
what is raised: a C library's callback (llvmlite's object-cache notifier, as numba loads a
cached kernel) or a weakref's (importlib's module locks), whose exceptions Python prints as
"Exception ignored in: ..." and drops. The command line keeps such a stop here
(fieldloc_cli.lazy_group, through ``sys.unraisablehook``) and the next commit
(stages.common.artifacts, a features file's frame parts, a report's move into its folder)
raises it before moving anything into place, so that a run whose stop was dropped commits
nothing more and says so, instead of running to its end as if no signal had come. Its own
module, of no imports, because the command line imports it before any command runs."""

from __future__ import annotations

DEFERRED_STOPS: list[BaseException] = []  # the first dropped stop not yet raised


def raise_deferred_stop() -> None:
    """Raise the stop kept in ``DEFERRED_STOPS``, if any (it is taken): the safe point of
    every commit."""
    if DEFERRED_STOPS:
        stop = DEFERRED_STOPS[0]
        DEFERRED_STOPS.clear()
        raise stop
