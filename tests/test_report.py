"""The report writer: Markdown and self-contained HTML with embedded figures."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from seagul_learn.report import Section, Table, library_versions, write_report


def test_write_report_embeds_figures_and_tables(tmp_path: Path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "curve.png")
    plt.close(fig)
    sections = [
        Section("Results", ["Adversarial beats **uniform** on `mse_initial`."], [Table(["a", "b"], [[1, 0.123456]])]),
        Section("Figures", figures=[("curve.png", "A curve"), ("missing.png", "Not there")]),
    ]
    md = write_report(tmp_path, "Test report", sections)
    text = md.read_text()
    assert md.name == "report.md"
    assert "| a | b |" in text and "| 1 | 0.1235 |" in text
    assert "![A curve](curve.png)" in text
    page = (tmp_path / "report.html").read_text()
    assert "data:image/png;base64," in page  # the existing figure is embedded
    assert "src='missing.png'" in page  # a missing one stays a link instead of failing
    assert "<b>uniform</b>" in page and "<code>mse_initial</code>" in page
    assert not list(tmp_path.glob("*.tmp"))


def test_library_versions_names_core_libraries():
    versions = library_versions()
    for name in ("python", "casadi", "torch", "gymnasium", "numpy"):
        assert versions[name] and versions[name] != "not installed"
