"""The solver: energies, contact, the linear algebra and the step (softhand_sim.physics.solver).

Importing any of it starts numba's thread pool first, before any kernel can run. Kernels with a
`prange` (pcg's row chunks, parallel's hands, two_level's sweeps) only work once the pool is up.
A cached kernel is supposed to start it when it is loaded, and does when it was compiled with its
parallel callees. But a caller compiled in a process that had loaded those callees from the cache
is saved without that duty (numba 0.68 keeps it on the compile result, not on the library a
cached callee links in). A later process that loads such a caller first, before any parallel
kernel, ran it on a pool that was never started and crashed (SIGSEGV in pcg's `_pcg`). That is
how a fresh clone's `make test` failed: its two workers compiled the cache between them.
tests/physics/test_thread_pool.py shows the crash in numba and that this import prevents it.
"""
import numba

numba.get_num_threads()  # starts the pool (NUMBA_NUM_THREADS threads) if it is not running yet
