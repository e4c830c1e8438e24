"""Simulator tests of the HDL (cocotb under Verilator and Icarus); current env only (scripts/test)."""
