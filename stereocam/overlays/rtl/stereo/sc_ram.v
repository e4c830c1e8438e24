// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_ram: rc_ram (simple dual-port, read data 2 clocks after its address) in slices of SLICE
 * bits side by side, one rc_ram each (the last one narrower where SLICE does not divide WIDTH).
 *
 * Why: a block RAM's aspect ratio is the tools' choice, and for a deep word they take the
 * narrowest count of blocks: 512 x 72 blocks several deep, whose outputs are then chosen by LUTs.
 * A slice as narrow as the block's deep mode (18 bits for 2K words, 9 for 4K) takes its words
 * one block deep, with no choice after it, for a few blocks more: the stereo core's RAMs have
 * block RAM to spare and not LUTs.
 *
 * Same ports, latency and behaviour as rc_ram. Parameters are checked at elaboration:
 * SLICE >= 1 (the rest as rc_ram checks them).
 */
module sc_ram #
(
    parameter WIDTH = 24,
    parameter DEPTH = 1024,
    parameter AW = $clog2(DEPTH),
    parameter SLICE = 18
)
(
    input  wire             clk,
    input  wire             we,
    input  wire [AW-1:0]    waddr,
    input  wire [WIDTH-1:0] wdata,
    input  wire             re,
    input  wire [AW-1:0]    raddr,
    output wire [WIDTH-1:0] rdata
);

localparam N = (WIDTH + SLICE - 1) / SLICE;

generate
    // verilator lint_off GENUNNAMED
    if (SLICE < 1) sc_ram_parameter_SLICE_must_be_at_least_1 slice_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

genvar k;
generate
    for (k = 0; k < N; k = k + 1) begin : g_slice
        localparam W = (k == N - 1) ? WIDTH - SLICE * (N - 1) : SLICE;
        rc_ram #(
            .WIDTH(W),
            .DEPTH(DEPTH),
            .AW(AW)
        )
        ram (
            .clk(clk),
            .we(we),
            .waddr(waddr),
            .wdata(wdata[SLICE*k +: W]),
            .re(re),
            .raddr(raddr),
            .rdata(rdata[SLICE*k +: W])
        );
    end
endgenerate

endmodule

`resetall
