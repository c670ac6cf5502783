"""JAX's own duration events (`jax.monitoring`) for one program's tracing, lowering and XLA
compilation, read by benchmarks.suite_compiles and benchmarks.first_batch."""

TRACE_EVENT = "/jax/core/compile/jaxpr_trace_duration"
LOWER_EVENT = "/jax/core/compile/jaxpr_to_mlir_module_duration"
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
