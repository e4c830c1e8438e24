"""What every command's refusal looks like: one line on stderr, exit code 2, no traceback."""
from __future__ import annotations

from typing import List

from stereocam.cli import main


def run_error(capsys, argv: List[str]) -> str:
    """Run ``stereocam *argv``, check it fails as a user error of its command, return the line."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"stereocam {argv[0]}: error: "), err
    assert "Traceback" not in err
    return err
