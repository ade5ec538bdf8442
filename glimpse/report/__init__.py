"""The run report: ``OUT/<scene>/report.html``, one page that shows what a run did and how well (written after
stage 07 and by ``glimpse report RUN``; docs/report.md)."""
