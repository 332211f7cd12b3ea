"""The CLI's rich console, one for every subcommand.

Rich draws 80 columns when its output is not a terminal (a log file, a pipe, CI): the study's
validation table then cut its verdicts to "vali…", which is the column a user reads first. Written
anywhere but a terminal, the console is 160 columns wide, unless ``COLUMNS`` says otherwise.
"""

from __future__ import annotations

import os

PIPED_WIDTH = 160


def cli_console(stderr: bool = False):
    from rich.console import Console

    console = Console(stderr=stderr)
    if not console.is_terminal and "COLUMNS" not in os.environ:
        console.width = PIPED_WIDTH
    return console
