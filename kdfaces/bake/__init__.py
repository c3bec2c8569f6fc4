"""Bakes of long takes on Dask: the final trajectory of every frame, computed in frame chunks by Dask tasks on a
local or an existing cluster, kept in a resumable zarr store, assembled into USD/PC2 point caches chunk by chunk
(``kdfaces bake``). Dask and zarr are imported only when a bake runs."""

from .bake import (
           OUTPUT_STORE_NAME,
           BakeResult,
           add_bake_parser,
           bake_shot,
           bake_summary,
           check_scheduler_address,
           default_store_path,
           export_bake,
           plan_bake,
)
from .store import BakeStore, chunk_key, content_digest
from .tasks import BakePayload, bake_chunk, code_fingerprint, input_fingerprint

__all__ = ["bake_shot", "BakeResult", "export_bake", "bake_summary", "default_store_path", "OUTPUT_STORE_NAME",
           "add_bake_parser", "check_scheduler_address", "plan_bake", "BakeStore", "chunk_key",
           "content_digest", "BakePayload", "bake_chunk", "code_fingerprint",
           "input_fingerprint"]
