// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_path_left: the path from the left (STEREO_CORE.md step 3, r = (-1, 0))
 * for all MAX_DISP disparities, one pixel a slot: the lane steps in two
 * halves of H = MAX_DISP / 2 lanes through one set of H units, the lane terms
 * in four quarters of Q = MAX_DISP / 4 through one set of Q units.
 *
 * `l_path` (lane d at [8*d +: 8]) gets its low half (lanes 0 .. H - 1) at
 * the end of phase 2 of each slot and its high half at the end of phase 3,
 * from `cost` (all MAX_DISP costs of the pixel, lane d at [6*d +: 6]; the low
 * half read at phase 2, the high half at phase 3), `first` (the previous
 * pixel is outside the image: L = C), `p2` (P2' of the pixel: P2 or
 * P2_EDGE), `p1` and `lane_ok` (lane d is below NUM_DISP; a masked lane is
 * loaded with 255, so it never lowers a minimum and never wins a neighbour
 * term), all held through phases 2 and 3. The lane terms min(L(d), L(d +- 1)
 * + P1) of the previous pixel are formed a quarter a clock as its halves
 * appear (quarter 0 at phase 3, 1 at 0, 2 at 1, 3 at 2) and its minimum by
 * one tree over a half (sc_min_tree, a register in its middle: the low
 * half's minimum at phase 0, the whole at phase 1).
 *
 * Latency: the pixel whose inputs are given at a slot's phases 2 and 3 has
 * its low half in `l_path` from that slot's phase 3 to the next slot's phase
 * 2, its high half from the next slot's phase 0 to its phase 3. Throughput:
 * one pixel a slot. Every register is enabled by `run`. No reset (data only:
 * a row starts with `first`). Parameters are checked at elaboration:
 * MAX_DISP >= 8, even.
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

localparam H = MAX_DISP / 2;
localparam Q = MAX_DISP / 4;

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (MAX_DISP < 8 || MAX_DISP % 4 != 0)
        sc_path_left_parameter_MAX_DISP_must_be_a_multiple_of_4_at_least_8 disp_wrong();
    // verilator lint_on GENUNNAMED
endgenerate

`include "sc_lane.vh"

// every half the lane steps produce, one clock later: the low half at phase 3, the high half at 0
reg [H*8-1:0] u;

// the minimum over the lanes of the previous pixel: a tree over the half in u (a register in its
// middle), the low half's minimum kept at phase 0, the whole at phase 1, held through phases 2, 3
wire [7:0] half_min;
sc_min_tree #(
    .N(H),
    .W(8),
    .STAGES(1),
    .OUT_REG(0),
    .ROOT_LEVELS($clog2(H) >= 3 ? 2 : 1)  // the root's side short: m's comparison follows it
)
min_inst (
    .clk(clk),
    .en(run),
    .in(u),
    .out(half_min)
);

reg [7:0] lo_min;
reg [7:0] m;
always @(posedge clk) begin
    if (run && phase == 2'd0) begin
        lo_min <= half_min;
    end
    if (run && phase == 2'd1) begin
        m <= half_min < lo_min ? half_min : lo_min;
    end
end

// The lane terms min(L(d), L(d +- 1) + P1) of the previous pixel, a quarter of Q lanes a clock
// through one set of Q units (the lane steps need them only at phases 2 and 3, but the halves of L
// they come from are made at phases 2 and 3 too: a quarter a clock keeps every unit busy).
// `window`: quarter q's lanes with a neighbour each side (lanes -1 and MAX_DISP are 255),
// registered the clock before its terms are formed: quarter 0 at phase 3 (from the low half as
// the lane steps make it), 1 at phase 0, 2 at phase 1, 3 at phase 2 (from l_path).
reg [(Q+2)*8-1:0] window;
always @(posedge clk) begin
    if (run) begin
        case (phase)
            2'd2: window <= {l_new[8*Q +: 8], l_new[0 +: 8*Q], 8'hFF};
            2'd3: window <= {l_new[0 +: 8], l_path[8*(Q-1) +: 8*(Q+1)]};
            2'd0: window <= {l_path[8*(H+Q) +: 8], l_path[8*(H-1) +: 8*(Q+1)]};
            default: window <= {8'hFF, l_path[8*(3*Q-1) +: 8*(Q+1)]};
        endcase
    end
end
wire [Q*9-1:0] terms;
genvar d;
generate
    for (d = 0; d < Q; d = d + 1) begin : g_term
        assign terms[9*d +: 9] = sc_lane_a(window[8*(d+1) +: 8], window[8*d +: 8], window[8*(d+2) +: 8], p1);
    end
endgenerate
// quarters 0..2 held until their half is due; `a` holds the half the lane steps work on: the low
// half (quarters 0, 1) at phase 2, the high half (2, 3) at phase 3
reg [Q*9-1:0] hold0, hold1, hold2;
reg [H*9-1:0] a;
always @(posedge clk) begin
    if (run && phase == 2'd3) begin
        hold0 <= terms;
    end
    if (run && phase == 2'd0) begin
        hold1 <= terms;
    end
    if (run && phase == 2'd1) begin
        hold2 <= terms;
        a <= {hold1, hold0};
    end
    if (run && phase == 2'd2) begin
        a <= {terms, hold2};
    end
end

// the lane steps, a half a clock: low at phase 2, high at phase 3
wire [H*6-1:0] cost_h = phase[0] ? cost[H*6 +: H*6] : cost[0 +: H*6];
wire [H-1:0] ok_h = phase[0] ? lane_ok[H +: H] : lane_ok[0 +: H];
wire [H*8-1:0] l_new;
generate
    for (d = 0; d < H; d = d + 1) begin : g_lane
        wire [5:0] c = cost_h[6*d +: 6];
        assign l_new[8*d +: 8] = sc_lane_l(c, a[9*d +: 9], m, p2, first, ok_h[d]);
    end
endgenerate

always @(posedge clk) begin
    if (run) begin
        u <= l_new;
    end
    if (run && phase == 2'd2) begin
        l_path[0 +: H*8] <= l_new;
    end
    if (run && phase == 2'd3) begin
        l_path[H*8 +: H*8] <= l_new;
    end
end

endmodule

`resetall
