"""Tables, figures and a Markdown report of a PSF interpolation study.

:func:`write_report` turns a :class:`sklearn_psf.study.compare.StudyResult` (or any object with the
same attributes) into a directory a person can read: the result tables (CSV and FITS), the
paper's figures as PNG files (see :mod:`sklearn_psf.study.plotting`) and ``report.md``. The report
checks the findings of Bergé et al. (2012) against the numbers of this study: every verdict
("agrees" / "disagrees") is computed from the tables, never written in advance.

:func:`summarize` gives the per-(config, scheme) medians and 16-84% ranges over simulations
used by the report and by the command line. :func:`survey_verdicts` and :func:`check_findings`
are the report's two analyses, usable on their own.

Sections: summaries and survey verdicts (``_summary``), the paper's findings (``_findings``),
the yardsticks (``_yardsticks``: metric definitions, the oracle, the verdicts' assumptions),
the figures (``_figures``), the text (``_markdown``), the files written (``_files``), the
report directory (``_write``) and a synthetic result for
examples and tests (``_synthetic``).
"""

from ._findings import check_findings
from ._summary import PAPER_SURVEYS, SUMMARY_METRICS, summarize, survey_verdicts
from ._synthetic import synthetic_study_result
from ._write import write_report

__all__ = [
    "PAPER_SURVEYS",
    "SUMMARY_METRICS",
    "summarize",
    "survey_verdicts",
    "check_findings",
    "write_report",
    "synthetic_study_result",
]
