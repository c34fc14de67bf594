"""hallray is the infrastructure both packages import: it imports neither of them, and it is
cheap (every command imports the harness at its start)."""

from __future__ import annotations

import subprocess
import sys


def test_hallray_imports_neither_package_nor_numpy():
    code = (
        "import sys\n"
        "import hallray, hallray.errors, hallray.harness, hallray.safe_output, hallray.units\n"
        "bad = sorted(m for m in sys.modules\n"
        "             if m.split('.')[0] in ('raytrace', 'positioning', 'numpy', 'scipy'))\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"


def test_positioning_error_is_the_shared_input_error():
    from hallray.errors import InputError
    from hallray.safe_output import OutputError
    from positioning import PositioningError

    assert issubclass(PositioningError, InputError) and issubclass(InputError, ValueError)
    assert issubclass(OutputError, InputError)
