// Language: Verilog 2005

`include "prelude.vh"

/*
 * rc_linebuf: one camera's line buffer, four block-RAM banks by row parity
 * and column parity (bank b = {row[0], col[0]}), so the four taps of a
 * bilinear neighbourhood, which lie in four different banks, are read in one
 * clock. rc_datapath computes the dense addresses (slot * CW + col / 2, see
 * there); a bank holds DEPTH words of WIDTH bits.
 *
 * Write: one word per clock into the bank {wrow_par, wcol_par}.
 * Read: the four banks at their own addresses (raddr, bank b at
 * [b*AW +: AW]) when `re` is 1; rdata (bank b at [b*WIDTH +: WIDTH]) 2 clocks
 * later (rc_ram), held until the next read.
 * Latency 2 clocks, throughput 1 read and 1 write per clock, no reset.
 * Parameters are checked at elaboration: WIDTH >= 1, DEPTH >= 2, 2**AW >= DEPTH.
 */
module rc_linebuf #
(
    parameter WIDTH = 24,
    parameter DEPTH = 15416,
    parameter AW = $clog2(DEPTH)
)
(
    input  wire               clk,

    input  wire               we,
    input  wire               wrow_par,
    input  wire               wcol_par,
    input  wire [AW-1:0]      waddr,
    input  wire [WIDTH-1:0]   wdata,

    input  wire               re,
    input  wire [4*AW-1:0]    raddr,
    output wire [4*WIDTH-1:0] rdata
);

genvar b;

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
// (rc_ram checks the same; here they name the line buffer, whose parameters rc_datapath computes)
generate
    // verilator lint_off GENUNNAMED
    if (WIDTH < 1) rc_linebuf_parameter_WIDTH_must_be_at_least_1 width_too_small();
    if (DEPTH < 2) rc_linebuf_parameter_DEPTH_must_be_at_least_2 depth_too_small();
    if ((1 << AW) < DEPTH) rc_linebuf_parameter_AW_too_small_for_DEPTH aw_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

generate
    for (b = 0; b < 4; b = b + 1) begin : g_bank
        rc_ram #(
            .WIDTH(WIDTH),
            .DEPTH(DEPTH),
            .AW(AW)
        )
        bank_inst (
            .clk(clk),
            .we(we && wrow_par == ((b / 2) != 0) && wcol_par == ((b % 2) != 0)),
            .waddr(waddr),
            .wdata(wdata),
            .re(re),
            .raddr(raddr[b*AW +: AW]),
            .rdata(rdata[b*WIDTH +: WIDTH])
        );
    end
endgenerate

endmodule

`resetall
