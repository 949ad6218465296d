"""Running ``depthguard`` (the library's commands) and ``depthguard-lab`` (the lab's) in this process, for the
command-line tests."""

from depthguard.cli import main
from depthguard_lab.cli import main as lab_main

#: The commands of ``depthguard-lab``; every other command is ``depthguard``'s.
LAB_COMMANDS = ("demo", "simulate", "workcell", "fusion-workcell", "scenario-a", "real-room")


def program(argv) -> str:
    """The program that runs the command ``argv[0]``: "depthguard-lab" or "depthguard"."""
    return "depthguard-lab" if argv and str(argv[0]) in LAB_COMMANDS else "depthguard"


def run_cli(argv, capsys):
    """(exit status, stdout, stderr) of ``depthguard argv`` (``depthguard-lab argv`` for a lab command) run in this
    process."""
    try:
        status = (lab_main if program(argv) == "depthguard-lab" else main)([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        status = exc.code
    out, err = capsys.readouterr()
    return status, out, err


def assert_refused(argv, capsys, *words) -> str:
    """``depthguard argv`` (or ``depthguard-lab argv``) exits 2 with nothing on stdout and one line on stderr,
    ``depthguard: error: ...``, no traceback, holding every one of ``words``. Returns that line."""
    status, out, err = run_cli(argv, capsys)
    assert status == 2, (argv, err)
    assert out == "" and "Traceback" not in err
    assert err.startswith(f"{program(argv)}: error: ") and err.count("\n") == 1, err
    for word in words:
        assert word in err, (word, err)
    return err
