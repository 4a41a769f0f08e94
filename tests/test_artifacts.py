"""mop_core/storage/artifacts.py: checkpoints written atomically and read back with errors that name the file,
content hashes, and learning curves as TSV."""

from __future__ import annotations

import hashlib
import pickle

import pytest
import torch

from mop_core.config import InputFileError
from mop_core.storage.artifacts import (
    file_sha256,
    load_checkpoint,
    read_torch_file,
    save_checkpoint,
    state_sha256,
    write_curve,
)


def _leftovers(directory):
    return sorted(p.name for p in directory.iterdir() if ".tmp-" in p.name)


def test_save_checkpoint_writes_through_a_temporary_file(tmp_path):
    path = tmp_path / "sub" / "run.pt"  # missing folders are made
    payload = {"kind": "test", "weights": torch.arange(4.0), "step": 3}
    assert save_checkpoint(path, payload) == path
    loaded = torch.load(path, weights_only=False)
    assert loaded["kind"] == "test" and loaded["step"] == 3 and torch.equal(loaded["weights"], torch.arange(4.0))
    assert _leftovers(path.parent) == []


def test_a_failed_save_leaves_the_previous_checkpoint_and_no_temporary_file(tmp_path):
    path = tmp_path / "run.pt"
    save_checkpoint(path, {"kind": "test", "step": 1})
    before = path.read_bytes()
    with pytest.raises((pickle.PicklingError, AttributeError)):
        save_checkpoint(path, {"kind": "test", "step": 2, "fn": lambda: None})  # a lambda does not pickle
    assert path.read_bytes() == before
    assert load_checkpoint(path, "test")["step"] == 1
    assert _leftovers(tmp_path) == []


def test_load_checkpoint_checks_the_kind(tmp_path):
    path = save_checkpoint(tmp_path / "teacher.pt", {"kind": "pbrl_teacher", "x": 1})
    assert load_checkpoint(path, "pbrl_teacher") == {"kind": "pbrl_teacher", "x": 1}
    with pytest.raises(InputFileError) as err:
        load_checkpoint(path, "mop_student")
    assert str(err.value) == f"{path}: expected a 'mop_student' checkpoint, found 'pbrl_teacher'"
    no_kind = save_checkpoint(tmp_path / "no_kind.pt", {"x": 1})
    with pytest.raises(InputFileError, match=r"expected a 'mop_student' checkpoint, found None$"):
        load_checkpoint(no_kind, "mop_student")
    not_a_dict = save_checkpoint(tmp_path / "list.pt", [1, 2])  # type: ignore[arg-type]
    with pytest.raises(InputFileError) as err:
        load_checkpoint(not_a_dict, "mop_student")
    assert str(err.value) == f"{not_a_dict}: expected a 'mop_student' checkpoint, found 'list'"


def test_read_torch_file_names_a_missing_empty_truncated_or_foreign_file(tmp_path):
    missing = tmp_path / "missing.pt"
    with pytest.raises(InputFileError) as err:
        read_torch_file(missing)
    assert str(err.value) == f"{missing}: checkpoint not found"
    with pytest.raises(InputFileError, match="checkpoint not found"):
        read_torch_file(tmp_path)  # a folder is no checkpoint
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    with pytest.raises(InputFileError) as err:
        read_torch_file(empty)
    assert str(err.value).startswith(f"{empty}: empty file (an interrupted copy?)")
    good = save_checkpoint(tmp_path / "good.pt", {"kind": "test", "w": torch.zeros(1000)})
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    foreign = tmp_path / "foreign.pt"
    foreign.write_text("step\treturn\n1\t2\n")
    for path in (truncated, foreign):
        with pytest.raises(InputFileError) as err:
            read_torch_file(path)
        message = str(err.value)
        assert message.startswith(f"{path}: not a readable torch checkpoint (truncated or corrupt?): ")
        assert "\n" not in message
    assert read_torch_file(good)["kind"] == "test"


def test_state_sha256_hashes_names_shapes_dtypes_and_bytes_in_key_order():
    state = {"b": torch.tensor([1.0, 2.0]), "a": torch.arange(6, dtype=torch.int64).reshape(2, 3)}
    digest = hashlib.sha256()
    for key in ("a", "b"):
        tensor = state[key]
        digest.update(f"{key}|{tuple(tensor.shape)}|{tensor.dtype}".encode())
        digest.update(tensor.numpy().tobytes())
    value = state_sha256(state)
    assert value == digest.hexdigest()
    assert state_sha256({"a": state["a"], "b": state["b"]}) == value  # insertion order does not matter
    variants = [
        {"b": torch.tensor([1.0, 2.5]), "a": state["a"]},  # a value
        {"b": state["b"], "a": state["a"].reshape(3, 2)},  # a shape, same bytes
        {"b": state["b"], "a": state["a"].to(torch.float64)},  # a dtype
        {"c": state["b"], "a": state["a"]},  # a name
    ]
    assert len({value, *(state_sha256(v) for v in variants)}) == 5
    # weights that need gradients, and a non-contiguous view, hash like their plain contiguous copy
    weight = torch.nn.Parameter(torch.arange(6.0).reshape(2, 3))
    assert state_sha256({"w": weight.t()}) == state_sha256({"w": torch.arange(6.0).reshape(2, 3).t().contiguous()})


def test_file_sha256_is_the_hash_of_the_bytes(tmp_path):
    path = tmp_path / "data.bin"
    data = bytes(range(256)) * 5000  # > 1 MiB: read in blocks
    path.write_bytes(data)
    assert file_sha256(path) == hashlib.sha256(data).hexdigest()
    assert file_sha256(str(path)) == file_sha256(path)
    empty = tmp_path / "empty"
    empty.write_bytes(b"")
    assert file_sha256(empty) == hashlib.sha256(b"").hexdigest()
    with pytest.raises(InputFileError) as err:
        file_sha256(tmp_path / "missing.pt")
    assert str(err.value) == f"{tmp_path / 'missing.pt'}: file not found"


def test_write_curve_writes_a_tsv_with_the_first_rows_columns(tmp_path):
    path = tmp_path / "curves" / "run.tsv"
    write_curve(path, [{"step": 10, "return_mean": 1.5, "loss": -2}, {"step": 20, "return_mean": 3.25, "loss": 0.5}])
    assert path.read_text() == "step\treturn_mean\tloss\n10\t1.5\t-2\n20\t3.25\t0.5\n"
    write_curve(path, [{"step": 1, "x": 2}])  # replaces the file
    assert path.read_text() == "step\tx\n1\t2\n"
    assert _leftovers(path.parent) == []
