"""Campaigns: many recordings of one project diagnosed on a Dask cluster, and the trend of each
named effect across them, with a drift test.

:func:`~.run.run_campaign` drives the cluster (:mod:`.cluster`) with one task per recording
(:mod:`.task`), turns the findings into trends (:mod:`.trends`) and writes ``campaign.json`` and
``campaign.html`` (:mod:`.page`). See ``docs/campaign.md``.
"""
