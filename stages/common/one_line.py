"""Every line fieldloc prints on stderr (a log line, the ``fieldloc: error:`` line, a summary)
goes through ``one_line``: one line, shown as it is by a terminal, of a bounded length,
whatever a name it quotes holds. A file or folder name may hold line breaks, ANSI escape
sequences (``ESC [1A ESC [2K`` moves a terminal's cursor up and erases the line above: a
log line could hide or fake earlier output) and be kilobytes long; the messages quote names
whole, and this is the one place that makes what they quote harmless.

``OneLineFormatter`` formats the log lines with it, in the CLI's process and in batch's
worker processes (``stderr_handler``)."""

from __future__ import annotations

import logging
import re
import sys

# the longest line fieldloc prints on stderr, its prefix ("fieldloc: error: ", "WARNING
# stages.extract: ") included: the harness of the trials flags longer lines, and a message
# quoting two paths of usual length and a sentence fits (its paths shortened first, see
# SHORTER_NAMES); a line of a name of kilobytes (a 4000-character path of spaced words) is
# cut in its middle to it, its head (what the message says) and tail (which file, and the
# reason after it) kept
LINE_MAX = 300
# the part of a cut line kept after the ellipsis: the end of the long name and what the
# message says after it (a reason in parentheses is about 40-90 characters)
LINE_TAIL = 110
# a run of characters without a space longer than this is a name of its own (a path, a
# value) and is cut in its middle to this, its head and tail kept: a line quoting two such
# names keeps the words between them
NAME_MAX = 120
# a line still longer than LINE_MAX has its names cut shorter, step by step, before the line
# itself is cut: the message's words are kept whole where its paths make it long
SHORTER_NAMES = (80, 60, 40)
ELLIPSIS = "..."

# what a terminal acts on instead of showing: the C0 controls (ESC, BEL, backspace, tab,
# ...), DEL, and the C1 controls (U+0080-U+009F; U+009B is a one-character "ESC [")
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")


def _escaped(m: re.Match) -> str:
    """A control character as Python's repr shows it: ``\\x1b``, ``\\t``, ``\\x9b``."""
    return repr(m.group(0))[1:-1]


def _middle_cut(text: str, keep: int, tail: int) -> str:
    """``text`` cut to ``keep`` characters, ``tail`` of them its end, the ellipsis between."""
    if len(text) <= keep:
        return text
    return text[:keep - tail - len(ELLIPSIS)] + ELLIPSIS + text[len(text) - tail:]


def _names_cut(text: str, longest: int) -> str:
    """``text``, each run of more than ``longest`` characters without a space cut in its
    middle to ``longest``."""
    return re.sub(rf"\S{{{longest + 1},}}",
                  lambda m: _middle_cut(m.group(0), longest, longest // 2), text)


def has_control(text: str) -> bool:
    """Whether ``text`` holds a character a terminal acts on instead of showing (a line
    break, ESC, ...): text read from a file to be printed in a table refuses one."""
    return _CONTROL.search(text) is not None


def one_line(text, limit: int = LINE_MAX) -> str:
    """``text`` as one line a terminal shows as it is, at most ``limit`` characters: a line
    break (of any kind) becomes a space, any other control character is shown escaped as
    Python's repr shows it (ESC as ``\\x1b``); a run of more than NAME_MAX characters without
    a space is cut in its middle to NAME_MAX; a line still longer than ``limit`` has such
    runs cut shorter (SHORTER_NAMES), and then, if need be, is cut in its middle."""
    text = _CONTROL.sub(_escaped, " ".join(str(text).splitlines()))
    text = _names_cut(text, NAME_MAX)
    for longest in SHORTER_NAMES:
        if len(text) <= limit:
            break
        text = _names_cut(text, longest)
    return _middle_cut(text, limit, min(LINE_TAIL, limit // 2))


class OneLineFormatter(logging.Formatter):
    """A log line is one line, as an error and a summary are (``one_line``: a line break in
    what a message quotes, a file called "a\\nb.png", is shown as a space, an escape sequence
    escaped, a name of kilobytes cut). A traceback (-vv, --debug) is appended after it as the
    logging module formats it."""

    def formatMessage(self, record: logging.LogRecord) -> str:
        return one_line(super().formatMessage(record))


LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"


def stderr_handler() -> logging.Handler:
    """The handler of fieldloc's log lines: on stderr, one line each (OneLineFormatter)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(OneLineFormatter(LOG_FORMAT))
    # known as fieldloc's own: silenced after an interrupt's last line (fieldloc_cli's
    # lazy_group), added once to a batch worker (stages.pipelines.batch)
    handler.fieldloc_stderr = True
    return handler
