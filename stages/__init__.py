"""fieldloc: self-localisation of RoboCup soccer robots from their camera images.

Every stage is callable from Python as ``main(conf, inputs..., output) -> Path`` and has a dict
of named presets ``confs``. The command line (``fieldloc_cli``) only parses and reports.
"""

__version__ = "0.1.0"
