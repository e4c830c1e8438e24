// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_path_up: one path from the row above (STEREO_CORE.md step 3: from above,
 * r = (0, -1), or from the upper right, r = (1, -1); sc_front instantiates it
 * twice), PARALLEL disparities a run clock, one pixel a slot.
 *
 * State: the previous row's L of every column in two banks of rc_ram slices (even
 * groups 0, 2 in bank 0, odd groups 1, 3 in bank 1; column x's group g at
 * address 2 x + g / 2, PARALLEL * 8 bits a word), each column's minimum over
 * the lanes in a third (MAX_WIDTH words of 8 bits). A bank is read at most
 * every other run clock, so each read's data is taken exactly 2 run clocks
 * later whatever gaps `run` has (rc_ram's output holds until the clock after
 * the bank's next read).
 *
 * Timing, in run clocks from phase 0 of the slot s0 that brought pixel
 * (x, y) into the front (slot s0 + k is run clocks 4k .. 4k + 3):
 *   5 + g   read group g of column xq (x above, x + 1 upper right) of the
 *           previous row (`rx1`, `ren1` of slot s0 + 1 for g = 0, 1, 2; `rx2`,
 *           `ren2` of slot s0 + 2 for g = 3); 6: read xq's minimum;
 *   9       take the minimum and the pixel's `first2` and `edge2` (slot s0 + 2);
 *   9 + g   the lane terms a = min(L(d), L(d +- 1) + P1) of group g (the
 *           group's word, the last lane of group g - 1, the first of g + 1);
 *   10 + g  L of group g: C (`cost_g`, the group of this run clock, see
 *           sc_front) + min(a - m, P2'), or C when `first2`; 255 in a masked
 *           group (`group_ok`); in `l_path` during 11 + g;
 *   11 + g  written to column `wx` (`wen`: the pixel is real; slot s0 + 2
 *           for g = 0, s0 + 3 for g = 1..3, sc_front's output stage);
 *   11 .. 16 the minimum of the pixel's lanes (a 2-stage tree and a running
 *           minimum over the groups), written to column `mwx` at 17 (`mwen`,
 *           slot s0 + 4).
 * So `l_path` holds group g = (phase + 1) mod 4 of the pixel of slot s0 + 2
 * at phase 3, of slot s0 + 3 at phases 0..2. A column is read before the row
 * below overwrites it (read at 5..8, written at 11..14 and 17; the upper
 * right path's column x + 1 is read by pixel x, written by pixel x + 1).
 *
 * Throughput: one pixel a slot. Every register and RAM read and write is
 * enabled by `run`. No reset (data only; writes are gated by the caller's
 * reset valid bits). Parameters are checked at elaboration:
 * MAX_DISP = 4 * PARALLEL, PARALLEL >= 4, MAX_WIDTH >= 2.
 */
module sc_path_up #
(
    parameter MAX_WIDTH = 752,
    parameter MAX_DISP = 128,
    parameter PARALLEL = 32,
    parameter XA = $clog2(MAX_WIDTH)
)
(
    input  wire                    clk,
    input  wire                    run,
    input  wire [1:0]              phase,

    input  wire [10:0]             rx1,
    input  wire                    ren1,
    input  wire [10:0]             rx2,
    input  wire                    ren2,
    input  wire                    first2,
    input  wire                    edge2,
    input  wire [PARALLEL*6-1:0]   cost_g,
    input  wire [3:0]              group_ok,
    input  wire [7:0]              p1,
    input  wire [7:0]              p2,
    input  wire [7:0]              p2_edge,

    input  wire [10:0]             wx,
    input  wire                    wen,
    input  wire [10:0]             mwx,
    input  wire                    mwen,

    output reg  [PARALLEL*8-1:0]   l_path
);

localparam LW = PARALLEL * 8;

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (MAX_DISP != 4 * PARALLEL || PARALLEL < 4)
        sc_path_up_parameter_MAX_DISP_must_be_4_times_PARALLEL_at_least_4 groups_wrong();
    if (MAX_WIDTH < 2) sc_path_up_parameter_MAX_WIDTH_must_be_at_least_2 width_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

`include "sc_lane.vh"

// ---- reads: group (phase + 3) mod 4; even groups from bank 0 at phases 1, 3 (a clock before the
// terms need them, so that the next group's first lane is a register by then, see below)
wire [10:0] rx = (phase == 2'd0) ? rx2 : rx1;
wire ren = (phase == 2'd0) ? ren2 : ren1;
wire [XA:0] raddr = {rx[XA-1:0], ~(phase[1] ^ phase[0])};

// ---- writes: group (phase + 1) mod 4 of l_path; even groups at phases 3, 1
wire [XA:0] waddr = {wx[XA-1:0], phase[0] ^ phase[1]};

// The two banks: bank 0 (even groups) is read and written at odd phases, bank 1 (odd groups) at
// even phases. Each in slices of 18 bits (rc_ram SLICE), a block RAM each as 2K x 18: a bank's
// 2 MAX_WIDTH words fit one deep. (As one 256-bit RAM, yosys maps a bank as 512 x 72 blocks three
// deep, and their output choice was 259 LUT a bank; the slices take 2.5 block RAMs more a bank.)
wire [LW-1:0] rdata_bank [0:1];
genvar b;
generate
    for (b = 0; b < 2; b = b + 1) begin : g_bank
        wire mine = phase[0] == (b == 0);
        rc_ram #(
            .WIDTH(LW),
            .DEPTH(2 * MAX_WIDTH),
            .AW(XA + 1),
            .SLICE(18)
        )
        ram (
            .clk(clk),
            .we(run && wen && mine),
            .waddr(waddr),
            .wdata(l_path),
            .re(run && ren && mine),
            .raddr(raddr),
            .rdata(rdata_bank[b])
        );
    end
endgenerate
wire [LW-1:0] rdata_e = rdata_bank[0];
wire [LW-1:0] rdata_o = rdata_bank[1];

// ---- each column's minimum
reg [7:0] run_min;
wire [7:0] rdata_m;

rc_ram #(
    .WIDTH(8),
    .DEPTH(MAX_WIDTH),
    .AW(XA)
)
ram_m (
    .clk(clk),
    .we(run && mwen && phase == 2'd1),
    .waddr(mwx[XA-1:0]),
    .wdata(run_min),
    .re(run && ren1 && phase == 2'd2),
    .raddr(rx1[XA-1:0]),
    .rdata(rdata_m)
);

// ---- the words: group (phase + 2) mod 4 arriving (nxt, read 2 run clocks ago), group
// (phase + 1) mod 4 in cur, group (phase + 3) mod 4, this run clock's lane terms', in cur2 with
// its neighbours `above` and `below` (all registers: the arriving word's first lane through the
// terms was a path over the period)
wire [LW-1:0] nxt = phase[0] ? rdata_e : rdata_o;
reg [LW-1:0] cur;
reg [LW-1:0] cur2;
// (a masked group g + 1 needs no test: its lanes were written as 255 in the row above)
// the neighbours beyond the terms' group, registered with the edges applied: `above` the next
// group's first lane (255 for group 3), `below` the last lane of the group before (255 for group
// 0); the terms' group is (phase + 3) mod 4, so the next run clock's is phase
reg [7:0] above;
reg [7:0] below;
always @(posedge clk) begin
    if (run) begin
        cur <= nxt;
        cur2 <= cur;
        above <= (phase == 2'd3) ? 8'hFF : nxt[7:0];
        below <= (phase == 2'd0) ? 8'hFF : cur2[LW-8 +: 8];
    end
end

wire [1:0] g_a = phase + 2'd3;  // the group of the lane terms
wire [LW+15:0] padded = {above, cur2, below};

reg [PARALLEL*9-1:0] a_reg;
genvar j;
generate
    for (j = 0; j < PARALLEL; j = j + 1) begin : g_terms
        always @(posedge clk) begin
            if (run) begin
                a_reg[9*j +: 9] <= sc_lane_a(padded[8*(j+1) +: 8], padded[8*j +: 8], padded[8*(j+2) +: 8], p1);
            end
        end
    end
endgenerate

// ---- the pixel's minimum over the previous row's lanes and its flags (phase 1)
reg [7:0] m_prev;
reg first_reg;
reg [7:0] p2_reg;
always @(posedge clk) begin
    if (run && phase == 2'd1) begin
        m_prev <= rdata_m;
        first_reg <= first2;
        p2_reg <= edge2 ? p2_edge : p2;
    end
end

// ---- L of group (phase + 2) mod 4
wire [1:0] g_l = phase + 2'd2;
generate
    for (j = 0; j < PARALLEL; j = j + 1) begin : g_lane
        wire [5:0] c = cost_g[6*j +: 6];
        always @(posedge clk) begin
            if (run) begin
                l_path[8*j +: 8] <= sc_lane_l(c, a_reg[9*j +: 9], m_prev, p2_reg, first_reg, group_ok[g_l]);
            end
        end
    end
endgenerate

// ---- this pixel's minimum: group (phase + 3) mod 4 leaves the tree
wire [7:0] t_min;
sc_min_tree #(
    .N(PARALLEL),
    .W(8),
    .STAGES(2)
)
min_inst (
    .clk(clk),
    .en(run),
    .in(l_path),
    .out(t_min)
);

always @(posedge clk) begin
    if (run) begin
        if (g_a == 2'd0 || t_min < run_min) begin
            run_min <= t_min;
        end
    end
end

endmodule

`resetall
