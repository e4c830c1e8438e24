// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_linebuf: the stereo core's 8-row circular line buffer, one rc_ram bank
 * per row slot (row r in bank r mod 8), 16 bits a pixel (left gray in 7:0,
 * right gray in 15:8), MAX_WIDTH words a bank.
 *
 * Write: one pixel per clock into bank `wslot` at column `wcol` (any clock,
 * from sc_input). Read: column `raddr` of all 8 banks at once when `re` is
 * 1; rdata (bank b at [16*b +: 16]) 2 clocks later (rc_ram), held until the
 * next read. Latency 2 clocks, throughput 1 read and 1 write per clock, no
 * reset. Parameters are checked at elaboration: MAX_WIDTH >= 2.
 */
module sc_linebuf #
(
    parameter MAX_WIDTH = 752,
    parameter AW = $clog2(MAX_WIDTH)
)
(
    input  wire           clk,

    input  wire           we,
    input  wire [2:0]     wslot,
    input  wire [AW-1:0]  waddr,
    input  wire [15:0]    wdata,

    input  wire           re,
    input  wire [AW-1:0]  raddr,
    output wire [127:0]   rdata
);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (MAX_WIDTH < 2) sc_linebuf_parameter_MAX_WIDTH_must_be_at_least_2 width_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

genvar b;
generate
    for (b = 0; b < 8; b = b + 1) begin : g_bank
        localparam [31:0] B32 = b;
        rc_ram #(
            .WIDTH(16),
            .DEPTH(MAX_WIDTH),
            .AW(AW)
        )
        bank_inst (
            .clk(clk),
            .we(we && wslot == B32[2:0]),
            .waddr(waddr),
            .wdata(wdata),
            .re(re),
            .raddr(raddr),
            .rdata(rdata[16*b +: 16])
        );
    end
endgenerate

endmodule

`resetall
