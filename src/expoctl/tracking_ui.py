"""Make the MLflow UI open an experiment where a user compares controllers: the runs table, leaderboard columns.

What MLflow 3.17.2's UI does on its own (read from its bundled JS, mlflow/server/js/build/static/js; the evidence is
in docs/pipeline.md#the-mlflow-ui):

- Which view an experiment opens on is decided in the browser, not by the experiment: a global "workflow type"
  (the sidebar's GenAI / Model training switch) taken from the URL's `?workflowType=` or else from local storage
  (`mlflow.workflowType_v1`), default `genai`; `/#/experiments/<id>` then redirects to the GenAI overview (or traces)
  and only `machine_learning` to the runs table. The experiment tag `mlflow.experimentKind` that older 3.x UIs read is
  ignored by 3.17 (its feature flag derives the kind from the workflow type); it is set all the same, as MLflow's own
  declaration of the kind, for UIs that read it.
- The runs table's columns, sort, filter and expanded rows are UI state in local storage, per browser. A *saved view*
  is the one piece of that state an experiment carries: an experiment tag `mlflow.sharedViewState.<id>` holding
  `{"name", "createdAt", "updatedAt", "state"}`, listed in the runs tab's "Views" menu and opened by
  `#/experiments/<id>/runs?viewStateShareKey=<id>`. Of the state it restores the search facets (filter, sort) and
  the columns; expanded rows it leaves out.
- Child runs are folded under their parent while the table is sorted by date with no filter; a filter (or a sort
  on a metric) lists them flat.

So `set_runs_view` writes a saved view with the chosen metric columns, sort and filter, and the experiment's
description (`mlflow.note.content`, shown above every tab, the GenAI overview included) links to it with
`workflowType=machine_learning`. It only writes tags that differ, so calling it on every stage run costs one read.

MLflow is imported inside the functions: the library must import without it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

KIND_TAG = "mlflow.experimentKind"
KIND_MODEL_DEVELOPMENT = "custom_model_development"  # the UI's "Machine learning" kind
NOTE_TAG = "mlflow.note.content"
VIEW_TAG_PREFIX = "mlflow.sharedViewState."
PRIMARY_METRIC_TAG = "mlflow.experiment.primaryMetric.name"
PRIMARY_METRIC_GREATER_TAG = "mlflow.experiment.primaryMetric.greaterIsBetter"
VIEW_ID = "expoctl-compare-controllers"
VIEW_NAME = "Compare controllers"
# the first line of the description this module writes: a description without it is a person's, and is kept
NOTE_MARKER = "**Compare controllers:**"
# wide enough for "dynamic.orb.min_nfm" and its value: the UI's default width cuts a metric's name to its first word
COLUMN_WIDTH_PX = 190


def column_key(kind: str, name: str) -> str:
    """The runs table's key of a column, as the UI writes it: `metrics.`dynamic.orb.min_nfm``."""
    if kind not in ("metrics", "params", "tags", "attributes"):
        raise ValueError(f"unknown column kind {kind!r}")
    return f"{kind}.`{name}`"


def runs_view_path(experiment_id: str, view_id: str = VIEW_ID) -> str:
    """The UI's address of the saved view, relative to the server root: `http://HOST:PORT/` + this."""
    return f"#/experiments/{experiment_id}/runs?viewStateShareKey={view_id}&workflowType=machine_learning"


def view_state(metrics: Sequence[str] = (), tags: Sequence[str] = (), params: Sequence[str] = (),
               order_by: str | None = None, ascending: bool = False, search_filter: str = "") -> dict[str, Any]:
    """The UI state a saved view restores: columns (tags, params, then metrics, in the order given), sort, filter.

    A sort on a metric also lists child runs flat (the UI folds them only under a date sort)."""
    columns = [*(column_key("tags", t) for t in tags), *(column_key("params", p) for p in params),
               *(column_key("metrics", m) for m in metrics)]
    # the run name and creation time are always shown; the default Source, Models and Dataset columns give way.
    # The UI applies saved widths only to the columns named in columnOrder, hence both.
    state: dict[str, Any] = {"selectedColumns": columns, "columnWidths": {c: COLUMN_WIDTH_PX for c in columns},
                             "columnOrder": columns,
                             "searchFilter": search_filter,
                             # the UI's default hides runs past the 10th in its charts; a leaderboard shows all
                             "runsHiddenMode": "SHOW_ALL"}
    if order_by:
        state["orderByKey"] = column_key("metrics", order_by)
        state["orderByAsc"] = ascending
    return state


def note_text(experiment_id: str, view_id: str = VIEW_ID, extra: str = "") -> str:
    """The experiment description: a link to the saved view, which a GenAI-first UI shows above its overview."""
    # one short line: the UI shows the description folded to its first line
    text = (f"{NOTE_MARKER} [the runs table with the leaderboard metrics]({runs_view_path(experiment_id, view_id)})"
            f" (sidebar *Model training* → *Views*)")
    return f"{text}\n\n{extra}" if extra else text


def set_runs_view(experiment_id: str, *, metrics: Sequence[str] = (), tags: Sequence[str] = (),
                  params: Sequence[str] = (), order_by: str | None = None, ascending: bool = False,
                  search_filter: str | None = None, note: str = "", view_id: str = VIEW_ID, view_name: str = VIEW_NAME,
                  tracking_uri: str | None = None) -> str:
    """Set an experiment up so the MLflow UI opens it on the runs table with these columns; return the view's path.

    Writes (only the tags whose value changes): `mlflow.experimentKind` = custom_model_development; a saved view
    `view_name` (columns: `tags`, `params`, `metrics`; sort: `order_by` metric, descending unless `ascending`;
    `search_filter` in MLflow's run search syntax, e.g. "tags.bench_id = '…'" to show one invocation's runs, None:
    the view's current filter, "" for a new view); the
    description linking to it (a description someone else wrote is kept); `order_by` as the experiment's primary
    metric. The store is `tracking_uri`, else MLflow's current one. Returns `runs_view_path(...)`."""
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    current = dict(client.get_experiment(experiment_id).tags)
    wanted = {KIND_TAG: KIND_MODEL_DEVELOPMENT}
    key = VIEW_TAG_PREFIX + view_id
    try:
        old = json.loads(current.get(key, ""))
        old_filter = json.loads(old["state"]).get("searchFilter", "")
    except (ValueError, TypeError, KeyError, AttributeError):
        old, old_filter = None, ""
    if search_filter is None:
        search_filter = old_filter
    state = json.dumps(view_state(metrics, tags, params, order_by, ascending, search_filter), sort_keys=True)
    if not (isinstance(old, dict) and old.get("state") == state and old.get("name") == view_name):
        now = int(time.time() * 1000)
        created = old.get("createdAt", now) if isinstance(old, dict) else now
        wanted[key] = json.dumps({"name": view_name, "createdAt": created, "updatedAt": now, "state": state})
    note = note_text(experiment_id, view_id, note)
    if not current.get(NOTE_TAG) or current[NOTE_TAG].startswith(NOTE_MARKER):
        wanted[NOTE_TAG] = note
    if order_by:
        wanted[PRIMARY_METRIC_TAG] = order_by
        wanted[PRIMARY_METRIC_GREATER_TAG] = str(not ascending)
    for k, v in wanted.items():
        if current.get(k) != v:
            client.set_experiment_tag(experiment_id, k, v)
    return runs_view_path(experiment_id, view_id)
