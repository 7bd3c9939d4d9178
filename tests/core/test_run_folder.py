"""The one run-folder reader: a directory or a job's files, each file through its record; what
an older run lacks is missing only to the use that asks for it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from modsat_core.artefacts import ArtefactError, DesignReport
from modsat_core.evaluation.run_folder import MissingRunFile, RunFolder
from modsat_core.evaluation.study_report import saved_run

#: A run kept from before policy files, trajectories and the removal of eight training keys
#: (its spec.json lists them at their no-op values).
OLD_RUN = Path(__file__).resolve().parents[1] / "data" / "reproduction" / "3x3x3" / "runs" / "td3-codesign-seed0"


def test_an_old_run_folder_opens_and_only_the_files_it_lacks_are_missing():
    run = RunFolder(OLD_RUN)
    assert run.name == "td3-codesign-seed0"
    assert run.spec().algorithm == "td3-codesign" and run.design().modules > 0
    assert run.evaluation().policy is not None and run.curve().points
    assert saved_run(run).spec == run.spec()  # the study report reads it through the same reader
    assert not run.has("trajectories.json") and run.read_optional("policy.pt") is None
    with pytest.raises(MissingRunFile, match=r"td3-codesign-seed0: no trajectories\.json"):
        run.trajectories()


def test_a_missing_folder_is_file_not_found_and_a_bad_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError):
        RunFolder(tmp_path / "nope")
    (tmp_path / "design.json").write_text("{not json")
    with pytest.raises(ArtefactError, match=r"design\.json is not JSON"):
        RunFolder(tmp_path).design()


def test_a_spec_this_version_refuses_is_named_and_still_readable_as_data(tmp_path):
    shutil.copytree(OLD_RUN, tmp_path / "run")
    spec = json.loads((tmp_path / "run" / "spec.json").read_text())
    spec["training"]["n_step"] = 3
    (tmp_path / "run" / "spec.json").write_text(json.dumps(spec))
    run = RunFolder(tmp_path / "run")
    with pytest.raises(ArtefactError, match=r"(?s)spec\.json: .*training\.n_step: removed"):
        run.spec()
    assert run.spec_data() == spec  # what the viewer shows of the run


def test_a_job_s_files_in_memory_read_the_same_and_none_is_missing():
    design = (OLD_RUN / "design.json").read_bytes()
    run = RunFolder("/api/jobs/7", {"design.json": design, "evaluation.json": None})
    assert run.design() == DesignReport.parse(design) and not run.has("evaluation.json")
    with pytest.raises(MissingRunFile, match=r"/api/jobs/7: no evaluation\.json"):
        run.evaluation()
