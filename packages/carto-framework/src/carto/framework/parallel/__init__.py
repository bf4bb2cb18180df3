"""Running work in tiles: progress bars with an ETA (:mod:`.progress`) and the tile engine
that runs tile tasks in this process, on threads, or on a ``dask.distributed`` cluster with
retries and failure records (:mod:`.engine`), and the coordinating process's freed memory
given back to the system between stages (:mod:`.process_memory`)."""
