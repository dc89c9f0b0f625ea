"""The fixed-rate runtime: the tick, the inbox, sessions, the kernels' warm-up and cache, memory
committed at start-up (docs/runtime.md)."""
