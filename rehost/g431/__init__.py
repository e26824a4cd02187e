"""Register-level models of the STM32G431 around the Unicorn engine's Cortex-M4, for running the firmware images
that ship."""
