"""Running ``depthguard`` in this process, for the command-line tests."""

from depthguard.cli import main


def run_cli(argv, capsys):
    """(exit status, stdout, stderr) of ``depthguard argv`` run in this process."""
    try:
        status = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        status = exc.code
    out, err = capsys.readouterr()
    return status, out, err


def assert_refused(argv, capsys, *words) -> str:
    """``depthguard argv`` exits 2 with nothing on stdout and one line on stderr, ``depthguard: error: ...``, no
    traceback, holding every one of ``words``. Returns that line."""
    status, out, err = run_cli(argv, capsys)
    assert status == 2, (argv, err)
    assert out == "" and "Traceback" not in err
    assert err.startswith("depthguard: error: ") and err.count("\n") == 1, err
    for word in words:
        assert word in err, (word, err)
    return err
