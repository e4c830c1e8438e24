// Language: Verilog 2005

// The directives every stereocam RTL file starts with, written once: the time unit and
// precision of the simulators, and no implicit nets (a misspelt signal is an error, not a
// new 1-bit wire). `resetall first, so nothing a file read before leaks into this one;
// each file ends with its own `resetall.
`resetall
`timescale 1ns / 1ps
`default_nettype none
