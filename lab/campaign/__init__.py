"""Campaigns: thousands of flights (Monte Carlo, grids) on a Dask cluster, from a laptop to many machines.

- :mod:`lab.campaign.spec`: the campaign file (base scenario, controllers, seeds, variations);
- :mod:`lab.campaign.units`: its units, with seeds derived from the campaign seed;
- :mod:`lab.campaign.flight`: one unit's flight, in-process or as SITL, and its result row;
- :mod:`lab.campaign.engine`: the Dask engine (local cluster or a scheduler), timeouts, dead workers;
- :mod:`lab.campaign.results`: ``results.csv``, appended as flights finish, read back to resume;
- :mod:`lab.campaign.summary`, :mod:`lab.campaign.figures`: tables, worst runs, figures;
- :mod:`lab.campaign.run`: a campaign into a results directory, resume, replay of one unit;
- :mod:`lab.campaign.cli`: ``smcpilot campaign run`` / ``replay``.

``smcpilot tune`` (:mod:`lab.tuning.study`) and ``smcpilot compare`` (:mod:`lab.compare`) fly
their flights as units of this engine. Guide: ``docs/campaigns.md``.
"""
