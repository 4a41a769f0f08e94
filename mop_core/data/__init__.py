"""Offline data: the HDF5 dataset schema with validated reads, and in-memory tensor buffers."""

from mop_core.data.buffer import Batch, ReplayBuffer, TransitionTensors
from mop_core.data.hdf5 import (
                                Dataset,
                                DatasetError,
                                read_dataset,
                                read_dataset_attrs,
                                read_relabel,
                                write_dataset,
                                write_relabel,
)
from mop_core.storage.files import atomic_path, read_json, write_json
from mop_core.storage.layout import LEVELS

__all__ = ["Batch", "Dataset", "DatasetError", "LEVELS", "ReplayBuffer", "TransitionTensors", "atomic_path",
           "read_dataset", "read_dataset_attrs", "read_json", "read_relabel", "write_dataset", "write_json",
           "write_relabel"]
