"""The compiled kernels of microlie: extension modules built from the C sources of this folder
by the package's ``setup.py`` (``pip install .``), reached only through
:func:`microlie._fast.module` (``None`` when a module was not built or ``MICROLIE_FAST=0``).
The build is optional: without a C compiler none of them exists and the generic NumPy kernels
run (``microlie --version`` says which are active).

``_lie.KERNELS`` maps each registry name (``"SE3.exp"``) to the function of ``_lie`` that
implements it; each function takes C-contiguous arrays of shape ``(N, k)``, all float64 or all
float32, and returns a tuple of fresh arrays of that dtype, one per output.

Outputs of 1 MB or more come from a small cache of freed blocks, so that a loop over large
batches reuses memory whose pages are already mapped instead of paying a page fault per 4 KB page
on every call: ``_lie.set_cache_limit(mb)`` (returns the previous limit) and the environment
variable ``MICROLIE_FAST_CACHE_MB`` bound the memory kept (default 256; 0 disables the cache),
plus one freed block above that limit (the latest; so a 288 MB Jacobian of 1e6 SE3 elements is
reused too; ``set_cache_limit`` releases it); ``_lie.cache_info()`` reports it (``"large"``).
A block is only reused after the array that owned it is freed.

``_text.parse_table`` reads numeric text tables (TUM, KITTI, EuRoC trajectory files) for
``microlie.traj.io``, with the values of Python's ``float`` (see ``_text.c``). ``_info.info()``
says which ISA the modules were built for and which version of the hot loops runs on this CPU
(``dispatch.h``).
"""
