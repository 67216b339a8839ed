"""Analyses of a campaign table: classification (Ch. 4), calibration against conventional
tests (Ch. 6) and sensory prediction (Ch. 7).

Every analysis reads a *table* (``properties.csv`` / ``.parquet`` of a campaign, or any table
with the same columns; see ``docs/campaign-table.md``), never run folders, so a user can feed
it numbers from elsewhere. Each analysis is one module over scikit-learn, statsmodels or
scipy.stats, with its own tables, plots and JSON; ``mbus-analyze`` is their command line.
"""
