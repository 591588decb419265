"""A fresh venv for the tests that install a package as a user does (pip install -e), with
tissuebench and its dependencies as installed here."""
from __future__ import annotations

import subprocess
import sys
import sysconfig
from pathlib import Path


def chained_venv(root: Path) -> Path:
    """A fresh venv whose site-packages chain this interpreter's (tissuebench and its dependencies,
    as installed here): ``venv --system-site-packages`` from inside a venv would reach the base
    interpreter's instead."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(root)], check=True)
    python = root / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    Path(purelib, "_chain_tissuebench.pth").write_text(
        f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    return python


def tissuebench_command(python: Path) -> Path:
    """``bin/tissuebench`` of the venv of ``python``: the console script pip writes for
    ``tissuebench.cli:main`` (the chained venv has tissuebench but not its script)."""
    script = python.parent / "tissuebench"
    script.write_text(f"#!{python}\nimport sys\nfrom tissuebench.cli import main\nsys.exit(main())\n")
    script.chmod(0o755)
    return script
