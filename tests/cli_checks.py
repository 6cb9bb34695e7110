"""Shared check of the command-line error contract: bad input is one ``error:`` line, exit code 2."""

import pytest


def one_line_error(call, capsys, *needles) -> str:
    """``call()`` exits with code 2 and one stderr line starting ``error:`` that contains every
    needle; returns that line."""
    with pytest.raises(SystemExit) as e:
        call()
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("error: "), err
    for n in needles:
        assert n in err[0], (n, err[0])
    return err[0]
