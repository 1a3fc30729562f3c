//! The STM32F411 board (drivers land next).
