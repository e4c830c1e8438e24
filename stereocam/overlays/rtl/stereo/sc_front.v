// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_front: the stereo core's front end, STEREO_CORE.md steps 1-3 ("RTL
 * structure": sc_census, sc_cost, sc_paths): from the line buffer to the
 * sums S(p, d) of the three paths, one disparity group of PARALLEL lanes per
 * run clock.
 *
 * Line buffer (sc_linebuf): 8 rows, written by sc_input through lb_*: pixel
 * (lb_col, lb_row) into row slot lb_row mod 8, any clock.
 *
 * Lockstep: `run` enables every register and RAM read and write of the front
 * (a clock without `run` changes nothing but line-buffer writes). A slot is 4
 * run clocks, `phase` 0..3; `row`, `col` (signed) are the pixel the slot
 * brings in, held for its 4 run clocks; the scheduler sweeps rows 0 ..
 * height + 2 and in each row columns -16 .. max(width, MAX_DISP + 32) - 1,
 * one slot a column. A pixel is real iff 0 <= row < height and
 * 0 <= col < width. When a slot of `row` runs, rows 0 .. min(row + 3,
 * height - 1) must be in the line buffer (the slot reads rows row - 3 ..
 * row + 3 of column col + 4 at its phase 0).
 *
 * Pipeline of the pixel brought in by slot s0 (run clocks from its phase 0):
 *   0       line buffer read of column x + 4;   2  window shift;
 *   3       census words and gray values (sc_census);
 *   3 + g   cost group g: its right census words picked; 4 + g stage 1;
 *           6 + g its costs (sc_cost), collected for the left path (all
 *           groups by 10);
 *   10, 11  the left path, lanes below MAX_DISP / 2, then the rest (sc_path_left);
 *   6 .. 13 the paths from above and the upper right (sc_path_up), group g
 *           in l_path during 11 + g;
 *   11 + g  S of group g = the three paths' L, loaded into m_*.
 *
 * Output: latency 3 slots. The m_* registers change only at the end of a run
 * clock; during the run clock of phase g of slot s0 + 3 they hold group g
 * (m_group = g = phase) of the pixel of slot s0: m_valid = 1 iff that pixel
 * is real, m_x, m_y its column and row, m_sum lane j (10 bits at [10*j +:
 * 10]) its S for disparity PARALLEL * g + j. Lanes at or above num_disp are
 * masked (left out of every minimum and neighbour term); their m_sum lanes
 * hold junk. m_valid is 0 during a run clock whose pixel is not real, and
 * the outputs hold between run clocks. A consumer in lockstep samples them at
 * its run clocks.
 *
 * Resources: the whole core's, in STEREO_CORE.md ("Resources (measured)"); the
 * front holds most of its block RAM (the two upper paths' rows, the line
 * buffer and the minima) and no DSP.
 *
 * Reset: synchronous, active high: the valid bits of the pipeline (so no
 * output and no path-state write before the first real pixel); data is not
 * reset. Parameters stable while a frame is processed.
 * Parameters are checked at elaboration: MAX_DISP = 4 * PARALLEL (G = 4),
 * PARALLEL >= 4, MAX_WIDTH 2 .. 2047.
 */
module sc_front #
(
    parameter MAX_WIDTH = 752,
    parameter MAX_DISP = 128,
    parameter PARALLEL = 32
)
(
    input  wire                     clk,
    input  wire                     rst,

    // line-buffer write port (from sc_input)
    input  wire                     lb_we,
    input  wire [10:0]              lb_col,
    input  wire [10:0]              lb_row,
    input  wire [15:0]              lb_data,

    // the active parameters
    input  wire [10:0]              width,
    input  wire [10:0]              height,
    input  wire [7:0]               num_disp,
    input  wire [7:0]               p1,
    input  wire [7:0]               p2,
    input  wire [7:0]               p2_edge,
    input  wire [7:0]               edge_thresh,

    // lockstep
    input  wire                     run,
    input  wire [1:0]               phase,
    input  wire signed [11:0]       row,
    input  wire signed [11:0]       col,

    // out: one disparity group per run clock
    output reg                      m_valid,
    output reg  [1:0]               m_group,
    output reg  [10:0]              m_x,
    output reg  [10:0]              m_y,
    output reg  [PARALLEL*10-1:0]   m_sum
);

localparam XA = $clog2(MAX_WIDTH);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (MAX_DISP != 4 * PARALLEL || PARALLEL < 4)
        sc_front_parameter_MAX_DISP_must_be_4_times_PARALLEL_at_least_4 groups_wrong();
    if (MAX_WIDTH < 2 || MAX_WIDTH > 2047)
        sc_front_parameter_MAX_WIDTH_must_be_2_to_2047 width_out_of_range();
    // verilator lint_on GENUNNAMED
endgenerate

wire slot_end = run && phase == 2'd3;

// ---- the masks: group g takes part iff num_disp > PARALLEL * g (num_disp a multiple of PARALLEL)
localparam [31:0] PAR32 = PARALLEL;
localparam [7:0] PAR8 = PAR32[7:0];
wire [3:0] group_ok = {num_disp > 3 * PAR8, num_disp > 2 * PAR8, num_disp > PAR8, num_disp != 8'd0};
wire [MAX_DISP-1:0] lane_ok = {{PARALLEL{group_ok[3]}}, {PARALLEL{group_ok[2]}},
                               {PARALLEL{group_ok[1]}}, {PARALLEL{group_ok[0]}}};

// ---- the pixel of each slot, carried along a slot at a time (dK: the pixel of slot s0 during s0 + K)
wire real0 = !row[11] && !col[11] && row[10:0] < height && col[10:0] < width;
wire [10:0] x0 = col[10:0];
wire [10:0] y0 = row[10:0];
wire [10:0] width_1 = width - 11'd1;

reg real1, real2, real3, real4;
reg [10:0] x1, x2, x3, x4, y1, y2;
reg first_l1, first_a1, first_u1, rd_a1, rd_u1;
reg first_l2, first_a2, first_u2, rd_a2, rd_u2;
reg edge_l2, edge_a2, edge_u2;
wire edge_l1, edge_a1, edge_u1;

always @(posedge clk) begin
    if (slot_end) begin
        real1 <= real0;
        x1 <= x0;
        y1 <= y0;
        first_l1 <= x0 == 11'd0;
        first_a1 <= y0 == 11'd0;
        first_u1 <= y0 == 11'd0 || x0 == width_1;
        rd_a1 <= real0 && y0 != 11'd0;
        rd_u1 <= real0 && y0 != 11'd0 && x0 != width_1;

        real2 <= real1;
        x2 <= x1;
        y2 <= y1;
        first_l2 <= first_l1;
        first_a2 <= first_a1;
        first_u2 <= first_u1;
        rd_a2 <= rd_a1;
        rd_u2 <= rd_u1;
        edge_l2 <= edge_l1;
        edge_a2 <= edge_a1;
        edge_u2 <= edge_u1;

        real3 <= real2;
        x3 <= x2;
        real4 <= real3;
        x4 <= x3;
    end
    if (rst) begin
        real1 <= 1'b0;
        real2 <= 1'b0;
        real3 <= 1'b0;
        real4 <= 1'b0;
        rd_a1 <= 1'b0;
        rd_u1 <= 1'b0;
        rd_a2 <= 1'b0;
        rd_u2 <= 1'b0;
    end
end

// ---- line buffer and census
wire lb_re;
wire [XA-1:0] lb_raddr;
wire [127:0] lb_rdata;

sc_linebuf #(
    .MAX_WIDTH(MAX_WIDTH),
    .AW(XA)
)
linebuf_inst (
    .clk(clk),
    .we(lb_we),
    .wslot(lb_row[2:0]),
    .waddr(lb_col[XA-1:0]),
    .wdata(lb_data),
    .re(lb_re),
    .raddr(lb_raddr),
    .rdata(lb_rdata)
);

wire [61:0] cl, cr;
wire [7:0] g_c, g_l, g_a, g_u;

sc_census #(
    .MAX_WIDTH(MAX_WIDTH),
    .AW(XA)
)
census_inst (
    .clk(clk),
    .run(run),
    .phase(phase),
    .row(row),
    .col(col),
    .width(width),
    .height(height),
    .lb_re(lb_re),
    .lb_raddr(lb_raddr),
    .lb_rdata(lb_rdata),
    .cl(cl),
    .cr(cr),
    .g_c(g_c),
    .g_l(g_l),
    .g_a(g_a),
    .g_u(g_u)
);

// edges along each path, during slot s0 + 1: |IL(p) - IL(q)| >= EDGE_THRESH
wire [8:0] diff_l = g_c > g_l ? {1'b0, g_c} - {1'b0, g_l} : {1'b0, g_l} - {1'b0, g_c};
wire [8:0] diff_a = g_c > g_a ? {1'b0, g_c} - {1'b0, g_a} : {1'b0, g_a} - {1'b0, g_c};
wire [8:0] diff_u = g_c > g_u ? {1'b0, g_c} - {1'b0, g_u} : {1'b0, g_u} - {1'b0, g_c};
assign edge_l1 = diff_l >= {1'b0, edge_thresh};
assign edge_a1 = diff_a >= {1'b0, edge_thresh};
assign edge_u1 = diff_u >= {1'b0, edge_thresh};

// ---- costs: group g in `cost` at phase g + 2; all groups collected in cost_all
wire [PARALLEL*6-1:0] cost;

sc_cost #(
    .MAX_DISP(MAX_DISP),
    .PARALLEL(PARALLEL)
)
cost_inst (
    .clk(clk),
    .rst(rst),
    .run(run),
    .phase(phase),
    .x(x1),
    .cl(cl),
    .cr(cr),
    .cost(cost)
);

localparam CW = PARALLEL * 6;
reg [MAX_DISP*6-1:0] cost_all;
wire [1:0] g_cost = phase + 2'd2;  // the group in `cost` now, and the group sc_path_up needs now
// (explicit selects: a part select at CW * g_cost is a barrel shifter to yosys)
always @(posedge clk) begin
    if (run && g_cost == 2'd0) begin
        cost_all[0 +: CW] <= cost;
    end
    if (run && g_cost == 2'd1) begin
        cost_all[CW +: CW] <= cost;
    end
    if (run && g_cost == 2'd2) begin
        cost_all[2*CW +: CW] <= cost;
    end
    if (run && g_cost == 2'd3) begin
        cost_all[3*CW +: CW] <= cost;
    end
end
// the group sc_path_up needs now is the one in `cost` 4 run clocks ago: a delay line, not a choice
// from cost_all (192 LUT); reset, so that no tool folds it into shift-register LUTs
reg [4*CW-1:0] cost_line;
always @(posedge clk) begin
    if (rst) begin
        cost_line <= {4*CW{1'b0}};
    end else if (run) begin
        cost_line <= {cost_line[3*CW-1:0], cost};
    end
end
wire [CW-1:0] cost_g = cost_line[3*CW +: CW];

// ---- the three paths
wire [MAX_DISP*8-1:0] l_left;

sc_path_left #(
    .MAX_DISP(MAX_DISP)
)
left_inst (
    .clk(clk),
    .run(run),
    .phase(phase),
    .cost(cost_all),
    .first(first_l2),
    .p1(p1),
    .p2(edge_l2 ? p2_edge : p2),
    .lane_ok(lane_ok),
    .l_path(l_left)
);

// the output stage's pixel: slot s0 + 2's, from its phase 3 to the next slot's phase 2
reg out_real;
reg [10:0] out_x, out_y;
always @(posedge clk) begin
    if (run && phase == 2'd2) begin
        out_real <= real2;
        out_x <= x2;
        out_y <= y2;
    end
    if (rst) begin
        out_real <= 1'b0;
    end
end

wire [PARALLEL*8-1:0] l_above, l_upright;

sc_path_up #(
    .MAX_WIDTH(MAX_WIDTH),
    .MAX_DISP(MAX_DISP),
    .PARALLEL(PARALLEL),
    .XA(XA)
)
above_inst (
    .clk(clk),
    .run(run),
    .phase(phase),
    .rx1(x1),
    .ren1(rd_a1),
    .rx2(x2),
    .ren2(rd_a2),
    .first2(first_a2),
    .edge2(edge_a2),
    .cost_g(cost_g),
    .group_ok(group_ok),
    .p1(p1),
    .p2(p2),
    .p2_edge(p2_edge),
    .wx(out_x),
    .wen(out_real),
    .mwx(x4),
    .mwen(real4),
    .l_path(l_above)
);

sc_path_up #(
    .MAX_WIDTH(MAX_WIDTH),
    .MAX_DISP(MAX_DISP),
    .PARALLEL(PARALLEL),
    .XA(XA)
)
upright_inst (
    .clk(clk),
    .run(run),
    .phase(phase),
    .rx1(x1 + 11'd1),
    .ren1(rd_u1),
    .rx2(x2 + 11'd1),
    .ren2(rd_u2),
    .first2(first_u2),
    .edge2(edge_u2),
    .cost_g(cost_g),
    .group_ok(group_ok),
    .p1(p1),
    .p2(p2),
    .p2_edge(p2_edge),
    .wx(out_x),
    .wen(out_real),
    .mwx(x4),
    .mwen(real4),
    .l_path(l_upright)
);

// ---- the sums of group (phase + 1) mod 4
wire [1:0] g_out = phase + 2'd1;
localparam LW = PARALLEL * 8;
wire [LW-1:0] l_left_g = g_out == 2'd0 ? l_left[0 +: LW]
                        : g_out == 2'd1 ? l_left[LW +: LW]
                        : g_out == 2'd2 ? l_left[2*LW +: LW]
                        : l_left[3*LW +: LW];
reg [PARALLEL*10-1:0] sums;
integer j;
always @* begin
    for (j = 0; j < PARALLEL; j = j + 1) begin
        sums[10*j +: 10] = {2'b00, l_left_g[8*j +: 8]} + {2'b00, l_above[8*j +: 8]}
                         + {2'b00, l_upright[8*j +: 8]};
    end
end

always @(posedge clk) begin
    if (run) begin
        m_valid <= out_real;
        m_group <= g_out;
        m_x <= out_x;
        m_y <= out_y;
        m_sum <= sums;
    end
    if (rst) begin
        m_valid <= 1'b0;
    end
end

endmodule

`resetall
