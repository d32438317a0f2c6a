"""Test campaigns: many closed-loop runs of many recordings, on a local pool or a Ray cluster.

A plan (:mod:`cam2sim.campaign.plan`) expands into run specs; an executor
(:mod:`cam2sim.campaign.executors`) runs each in a worker (:mod:`cam2sim.campaign.worker`);
:mod:`cam2sim.campaign.runner` keeps the state and resumes, :mod:`cam2sim.campaign.summary`
scores the runs and writes the tables. This package builds on the stages; nothing depends on it.
"""
