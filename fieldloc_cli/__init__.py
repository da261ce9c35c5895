"""The command line of fieldloc: parses options, shows progress, reports errors. No algorithms."""
