"""The model as firmware: portable C99 generated from a model artifact (`codegen`), cross-compiled for a
Cortex-M4F into a flashable ELF (`toolchain`). The emulator that runs the ELF is `target_sim.firmware`.

The generated C and `target_sim.model` (the Python float32 reference) are the same computation, operation for
operation, so the ELF run in the emulator gives the reference's outputs bit for bit (tests/bench/firmware).
"""
