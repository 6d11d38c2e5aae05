"""Many captures fitted as one batch on Ray, on this machine or a cluster (docs/batch.md).

python -m torchrefl.batch BATCH.yaml [--address ADDR]; the Python API is run_batch(read_batch(path)).
"""

from torchrefl.batch.batch_file import BatchFile, BatchTask, read_batch
from torchrefl.batch.runner import run_batch
from torchrefl.batch.summary import Row

__all__ = ["BatchFile", "BatchTask", "Row", "read_batch", "run_batch"]
