// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * sc_path_left: the path from the left (STEREO_CORE.md step 3, r = (-1, 0))
 * for all MAX_DISP disparities at once, one pixel a slot.
 *
 * `l_path` (lane d at [8*d +: 8]) is loaded at the end of phase 2 of each
 * slot from `cost` (all MAX_DISP costs of the pixel, lane d at [6*d +: 6]),
 * `first` (the previous pixel is outside the image: L = C), `p2` (P2' of
 * the pixel: P2 or P2_EDGE), `p1` and `lane_ok` (lane d is below NUM_DISP;
 * a masked lane is loaded with 255, so it never lowers a minimum and never
 * wins a neighbour term). Between two loads the unit prepares the next: the
 * lane terms min(L(d), L(d +- 1) + P1) in one register stage and the minimum
 * over the lanes in a 3-stage tree (sc_min_tree), both ready at phase 2.
 *
 * Latency: the inputs at a slot's phase 2 are in `l_path` from its phase 3
 * until the next slot's phase 2 (4 run clocks). Throughput: one pixel a slot.
 * Every register is enabled by `run`. No reset (data only: a row starts
 * with `first`). Parameters are checked at elaboration: MAX_DISP >= 8.
 */
module sc_path_left #
(
    parameter MAX_DISP = 128
)
(
    input  wire                    clk,
    input  wire                    run,
    input  wire [1:0]              phase,
    input  wire [MAX_DISP*6-1:0]   cost,
    input  wire                    first,
    input  wire [7:0]              p1,
    input  wire [7:0]              p2,
    input  wire [MAX_DISP-1:0]     lane_ok,
    output reg  [MAX_DISP*8-1:0]   l_path
);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule
generate
    if (MAX_DISP < 8) begin : g_check_disp
        sc_path_left_parameter_MAX_DISP_must_be_at_least_8 disp_too_small();
    end
endgenerate

`include "sc_lane.vh"

// the minimum over the lanes of l_path: 3 stages, ready at the next phase 2
wire [7:0] m;
sc_min_tree #(
    .N(MAX_DISP),
    .W(8),
    .STAGES(3)
)
min_inst (
    .clk(clk),
    .en(run),
    .in(l_path),
    .out(m)
);

// the neighbours of each lane, 255 outside the range
wire [(MAX_DISP+2)*8-1:0] padded = {8'hFF, l_path, 8'hFF};

genvar d;
generate
    for (d = 0; d < MAX_DISP; d = d + 1) begin : g_lane
        reg [8:0] a_reg;
        always @(posedge clk) begin
            if (run) begin
                a_reg <= sc_lane_a(padded[8*(d+1) +: 8], padded[8*d +: 8], padded[8*(d+2) +: 8], p1);
            end
        end
        wire [5:0] c = cost[6*d +: 6];
        always @(posedge clk) begin
            if (run && phase == 2'd2) begin
                if (!lane_ok[d]) begin
                    l_path[8*d +: 8] <= 8'hFF;
                end else if (first) begin
                    l_path[8*d +: 8] <= {2'b00, c};
                end else begin
                    l_path[8*d +: 8] <= sc_lane_step(c, a_reg, m, p2);
                end
            end
        end
    end
endgenerate

endmodule

`resetall
