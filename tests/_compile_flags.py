"""XLA:CPU flags for the test processes (no imports: read before jax is)."""

#: LLVM at -O0 and XLA's legacy (non-MLIR) fusion emitters.  The program's math is the
#: one users get (the same HLO up to fusion: the legacy emitters group a few
#: elementwise operations differently); its machine code is slower, and the suite's small
#: programs compile 30-40% faster (docs/notebook.md, "the suite's compile flags").
FAST_COMPILE_FLAGS = "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"


def with_fast_compile(env: dict) -> dict:
    """A copy of ``env`` whose ``XLA_FLAGS`` add :data:`FAST_COMPILE_FLAGS`."""
    flags = " ".join(f for f in (env.get("XLA_FLAGS", ""), FAST_COMPILE_FLAGS) if f)
    return dict(env, XLA_FLAGS=flags)


#: The same two options at XLA:CPU's defaults, as ``compiler_options`` for one compile
#: (``_helpers.as_users_compile``): a test that compares two programs bit for bit compiles
#: them as users' code is, where the legacy emitters may group a sum apart.
USERS_COMPILER_OPTIONS = {"xla_backend_optimization_level": 2, "xla_cpu_use_fusion_emitters": True}
