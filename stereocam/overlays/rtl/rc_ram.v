// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * rc_ram: simple dual-port RAM, one write port and one read port on one
 * clock, written as a plain inferred array so that yosys and Vivado map it
 * to block RAM (the depth need not be a power of two).
 *
 * Latency: read data 2 clocks after the read address: the array's registered
 * read, then an output register (a block RAM's DO_REG in Vivado), each
 * loaded only for a read (`re`, and `re` one clock later), so the data holds
 * until the next read. Throughput: one write and one read per clock.
 * A read of the address written in the same clock returns the old data
 * (the line buffer never does that: see rc_datapath).
 * No reset (block RAM contents and its output register are not reset).
 */
module rc_ram #
(
    parameter WIDTH = 24,
    parameter DEPTH = 1024,
    parameter AW = $clog2(DEPTH)
)
(
    input  wire             clk,

    input  wire             we,
    input  wire [AW-1:0]    waddr,
    input  wire [WIDTH-1:0] wdata,

    input  wire             re,
    input  wire [AW-1:0]    raddr,
    output reg  [WIDTH-1:0] rdata
);

(* ram_style = "block" *)
reg [WIDTH-1:0] mem [0:DEPTH-1];

always @(posedge clk) begin
    if (we) begin
        mem[waddr] <= wdata;
    end
end

reg [WIDTH-1:0] read_reg;
reg             re_reg = 1'b0;

always @(posedge clk) begin
    if (re) begin
        read_reg <= mem[raddr];
    end
    re_reg <= re;
    if (re_reg) begin
        rdata <= read_reg;
    end
end

endmodule

`resetall
