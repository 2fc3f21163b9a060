"""The documentation site builds with warnings as errors (MkDocs, strict), and its generated pages are current."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs")
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    for page in ("environments", "use_with", "guide", "policies", "benchmark", "migration", "deviations", "results"):
        assert (tmp_path / "site" / page / "index.html").is_file(), page
    shutil.rmtree(tmp_path / "site")


def test_every_page_is_in_the_navigation():
    yaml = pytest.importorskip("yaml")

    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]
    listed = {next(iter(entry.values())) for entry in nav}
    assert listed == {p.name for p in (ROOT / "docs").glob("*.md")}
