"""What a plan covers: reports, measured coverage, figures and progress.

Public face: :class:`~.report.CoverageReport`, :func:`~.coverage.measured_coverage`,
:func:`~.coverage_figure.plot_coverage`, :data:`~.progress.STAGES`.

Modules: ``report`` (coverage report and metadata of a run, uncertainties, masks, scan lines), ``coverage``
(measured against predicted coverage, colours), ``coverage_figure`` (the PNG figure), ``progress`` (the stages).
"""
