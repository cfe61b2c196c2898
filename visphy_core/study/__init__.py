"""Studies: a Hydra multirun evaluated, tracked and analysed as one unit.

``python -m visphy_core -m experiment=<study>`` runs every job of the study's sweep (declared in
``conf/experiment/<study>.yaml``). The Hydra callback (`callback.StudyCallback`, enabled in
``conf/hydra/callbacks/visphy_study.yaml``) opens a parent MLflow run, tells each job where the
study file is so that its run becomes a child of the parent (also when a launcher runs jobs in
other processes or on other machines: only files in the sweep dir are shared), records each
job's run directory, and at the end runs the study analysis and report (`finish`).

Modules: `records` (the study file and the per-job records), `callback` (the Hydra hooks),
`finish` (collect the jobs' runs, analyse, report, log to the parent run).
"""
