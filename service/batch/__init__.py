"""Re-analysis of many recordings on a Dask cluster (``graytrack batch``) and the drift report
(``graytrack history``) built from its summaries."""
