"""The README's Python example runs as a script, as printed (smaller sizes substituted).

Dask's worker processes re-import the main script, so the example must guard its work with
``if __name__ == "__main__":``; this test saves it to a file and runs it in a fresh
interpreter, so a missing guard (or any API drift) fails here.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# (as printed, for this test): keep the run to seconds; each must be found in the README
SMALLER = [
    ("bits=2048", "bits=256"),
    ("hevr.phantom(64)", "hevr.phantom(12)"),
    ("brick=32", "brick=6"),
    ("width=150, height=150", "width=20, height=16"),
]


def _example() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README.md has no ```python block"
    return blocks[0]


def test_readme_example_has_a_main_guard():
    assert 'if __name__ == "__main__":' in _example()


def test_readme_example_runs_as_a_script(tmp_path):
    code = _example()
    for old, new in SMALLER:
        assert old in code, f"README example changed: {old!r} not found (update this test)"
        code = code.replace(old, new)
    script = tmp_path / "example.py"
    script.write_text(code, encoding="utf-8")
    run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    for name in ("key.json", "key.pub.json", "tf.png", "tf2.png", "vol.zarr"):
        assert (tmp_path / name).exists(), name
    assert (tmp_path / "tf.png").read_bytes() != (tmp_path / "tf2.png").read_bytes()  # re-coloured
    assert (tmp_path / "key.json").stat().st_mode & 0o777 == 0o600
