"""A merged run's MLflow family: each shard's MLflow run (in the merged run's store) becomes the
merged run's child; when the shards were all children of one run (a study's parent), the merged
run becomes that run's child instead. The run context's ``merged_from`` (written by
`visphy_core.execute.merge`) names each shard's run and store."""

from __future__ import annotations

import logging

log = logging.getLogger("visphy.tracking")


def adopt_shard_runs(client, merged_run_id: str, tracking_uri: str,
                     merged_from: list[dict]) -> list[str]:
    """Link the shards' runs of ``merged_from`` under ``merged_run_id``; returns the run ids
    linked. A shard tracked in another store is named in a warning and left alone."""
    linked, parents, study = [], set(), None
    for shard in merged_from:
        run_id = shard.get("mlflow_run_id")
        if not run_id:
            continue
        if shard.get("mlflow_tracking_uri") != tracking_uri:
            log.warning("merge: the MLflow run of shard %s is in %s, not in %s: not linked",
                        shard.get("shard"), shard.get("mlflow_tracking_uri"), tracking_uri)
            continue
        tags = client.get_run(run_id).data.tags
        parents.add(tags.get("mlflow.parentRunId"))
        study = tags.get("visphy.study") or study
        client.set_tag(run_id, "mlflow.parentRunId", merged_run_id)
        client.set_tag(run_id, "visphy.merged_into", merged_run_id)
        linked.append(run_id)
    client.set_tag(merged_run_id, "visphy.merged_shards", str(len(merged_from)))
    if len(parents) == 1 and None not in parents:
        client.set_tag(merged_run_id, "mlflow.parentRunId", parents.pop())
        if study:
            client.set_tag(merged_run_id, "visphy.study", study)
    return linked
