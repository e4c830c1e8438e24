// Language: Verilog 2005

`include "prelude.vh"

`include "stereo_spec.vh"

/*
 * sc_winners: steps 4 to 6 of the stereo core (STEREO_CORE.md) for each pixel: the winner d1
 * and its sum S1, the runner-up S2 (the lowest sum more than one disparity away), the sub-pixel
 * code, the uniqueness and border tests and the confidence.
 *
 * In: the front's sums, one group of PARALLEL disparities a clock (`s_valid`; groups 0 .. G-1 of
 * a pixel in order, not necessarily in consecutive clocks, G = MAX_DISP / PARALLEL = 4). Lanes at
 * or above `num_disp` are ignored.
 * Out: one record a pixel (`r_valid` for one clock), in the order the pixels came.
 * How: a first pass takes the minimum of each group as it arrives (a pipelined 32-way tree) into
 * a running minimum; the sums are kept in one of two buffers; once d1 is known a second pass
 * reads the buffer group by group for S2 and the sums beside d1. The next pixel but one writes a
 * group of that buffer at the end of the clock the second pass reads it at the earliest, and the
 * buffers are read without a clock (LUT RAM), so the read takes the sums before the write (the
 * second pass starts 5 clocks after the last group and reads one group a clock; the writer's
 * group g comes 5 + g clocks after it at the earliest).
 * Then two restoring dividers: the sub-pixel offset (4 quotient bits) and the confidence (9).
 * Latency: 22 clocks from a pixel's last group to its record. Free running (no enable): it only
 * needs its input's order.
 *
 * And the right image's winners for step 7's left-right check (STEREO_CORE.md, step 6):
 * dR(xr) = the d with the lowest S(xr + d, d), the lowest d on ties, over d < num_disp and
 * xr + d < width, from the same sums as the left winners (no second pass over the images).
 *
 * A systolic array of MAX_DISP cells: after pixel x of a row, cell k holds the best (sum, d) so
 * far of the right image's column x - k. Each pixel shifts the array by one (a new row starts it
 * empty) and updates cell k with its lane for d = k (cell k takes S(x, k) when x - k >= 0,
 * k < num_disp and it is strictly lower: d grows with x, so the lowest d wins ties). The cells
 * are kept as G words of PARALLEL, one per group, and each group as it arrives shifts and updates
 * its own word through one set of PARALLEL comparators (a comparator a cell was 2.7k LUT more).
 * The cell shifted out of the last place is final (it has seen every d); so is every cell once a
 * row's last pixel is in (`width - 1`): those are copied to a flush buffer and written one a
 * clock.
 * Out: a write port for the winners' RAM: address (row mod 3) * MAX_WIDTH + xr, 7-bit d.
 * Free running (no enable), from the front's groups in order. A row's winners are all written at
 * most `width` + 2 clocks after its last group.
 * Reset: synchronous, active high.
 */
module sc_winners #
(
    parameter MAX_WIDTH = 752,
    parameter MAX_DISP = 128,
    parameter PARALLEL = 32,
    parameter AW = $clog2(3 * MAX_WIDTH)
)
(
    input  wire                           clk,
    input  wire                           rst,
    input  wire [10:0]                    width,
    input  wire [7:0]                     num_disp,
    input  wire [7:0]                     uniqueness,
    input  wire                           subpixel,

    input  wire                           s_valid,
    input  wire [1:0]                     s_group,
    input  wire [10:0]                    s_x,
    input  wire [10:0]                    s_y,
    input  wire [PARALLEL*`SC_SUM_W-1:0]  s_sum,

    // the left winners: a record a pixel
    output reg                            r_valid = 1'b0,
    output reg  [10:0]                    r_x,
    output reg  [10:0]                    r_y,
    output reg  [6:0]                     r_d1,
    output reg  [10:0]                    r_code,
    output reg  [7:0]                     r_conf,
    output reg                            r_unique,
    output reg                            r_border,

    // the right winners: the write port of their RAM
    output reg                            w_en = 1'b0,
    output reg  [AW-1:0]                  w_addr,
    output reg  [6:0]                     w_d
);

`include "sc_bank.vh"

localparam SW = `SC_SUM_W;
localparam LW = $clog2(PARALLEL);      // lane index bits
localparam G = MAX_DISP / PARALLEL;
localparam [SW-1:0] BIG = {SW{1'b1}};
localparam [31:0] PAR32 = PARALLEL;
localparam [10:0] PAR11 = PAR32[10:0];

generate
    if (G != 4) sc_winners_needs_MAX_DISP_equal_4_PARALLEL groups_not_4();
endgenerate

// ---- a 32-way (PARALLEL-way) minimum with its lane, lowest lane on ties, in two registered halves
function [SW+LW-1:0] pick;  // {value, lane} of the smaller of two, the first on ties
    input [SW+LW-1:0] a;
    input [SW+LW-1:0] b;
    begin
        pick = (b[SW+LW-1:LW] < a[SW+LW-1:LW]) ? b : a;
    end
endfunction

localparam SC_KEY_W = SW;
`include "sc_least4.vh"

// {value, lane} of the least of four, the first on ties (a choice of four: shorter than two levels
// of picks in a row)
function [SW+LW-1:0] pick4;
    input [SW+LW-1:0] a;
    input [SW+LW-1:0] b;
    input [SW+LW-1:0] c;
    input [SW+LW-1:0] d;
    reg [1:0] first;
    begin
        first = sc_least4(a[SW+LW-1:LW], b[SW+LW-1:LW], c[SW+LW-1:LW], d[SW+LW-1:LW]);
        pick4 = first == 2'd0 ? a : first == 2'd1 ? b : first == 2'd2 ? c : d;
    end
endfunction


// ---- the sum buffers: two pixels' worth
reg [PARALLEL*SW-1:0] buf0 [0:G-1];
reg [PARALLEL*SW-1:0] buf1 [0:G-1];
reg                   wbuf = 1'b0;  // the buffer the arriving pixel writes

always @(posedge clk) begin
    if (s_valid) begin
        if (wbuf) buf1[s_group] <= s_sum; else buf0[s_group] <= s_sum;
    end
    if (rst) begin
        wbuf <= 1'b0;
    end else if (s_valid && s_group == G - 1) begin
        wbuf <= ~wbuf;
    end
end

// ---- first pass: mask, tree, running minimum
// a group's tag through the first pass: {ok (below num_disp), buffer, y, x, group}
localparam TAG_W = 26;
reg                   a0_valid = 1'b0;
reg [TAG_W-1:0]       a0_tag;
reg [PARALLEL*(SW+LW)-1:0] a0_lanes;

integer i1;
integer i2;
integer i3;
integer i4;
integer i5;
integer i7;
integer i8;
integer i9;
integer i11;
integer i12;
integer i13;
// A group takes part iff its first disparity is below num_disp (a multiple of PARALLEL: sc_regs
// refuses any other), so one test a group serves all its lanes.
wire s_group_ok = {9'd0, s_group} * PAR11 < {3'd0, num_disp};
always @(posedge clk) begin
    a0_valid <= s_valid && !rst;
    // (a group at or above num_disp: its least sum is made BIG after the tree)
    a0_tag <= {s_group_ok, wbuf, s_y, s_x, s_group};
    for (i2 = 0; i2 < PARALLEL; i2 = i2 + 1) begin
        a0_lanes[i2*(SW+LW) +: SW+LW] <= {s_sum[i2*SW +: SW], i2[LW-1:0]};
    end
end

// The tree in two stages (a choice of four, then pairs: PARALLEL -> R, 32 -> 4; then R -> 1, by a
// choice of four for R = 4), then the running minimum over the groups in a third: a tree to 4 and
// two more levels and the running minimum in one clock, and two choices of four in a row, were
// paths over the period.
localparam R1 = PARALLEL / 4;
localparam R = (R1 >= 2) ? R1 / 2 : 1;
reg                   a1_valid = 1'b0;
reg [TAG_W-1:0]       a1_tag;
reg [R*(SW+LW)-1:0]   a1_lanes;
reg [SW+LW-1:0] t1 [0:R1-1];
reg [SW+LW-1:0] t2 [0:R-1];
always @* begin
    for (i3 = 0; i3 < R1; i3 = i3 + 1)
        t1[i3] = pick4(a0_lanes[(4*i3)*(SW+LW) +: SW+LW], a0_lanes[(4*i3+1)*(SW+LW) +: SW+LW],
                       a0_lanes[(4*i3+2)*(SW+LW) +: SW+LW], a0_lanes[(4*i3+3)*(SW+LW) +: SW+LW]);
end
generate
    if (R1 >= 2) begin : g_t2_pairs
        always @* begin
            for (i4 = 0; i4 < R; i4 = i4 + 1)
                t2[i4] = pick(t1[2*i4], t1[2*i4+1]);
        end
    end else begin : g_t2_same
        always @* t2[0] = t1[0];
    end
endgenerate
always @(posedge clk) begin
    a1_valid <= a0_valid && !rst;
    a1_tag <= a0_tag;
    for (i11 = 0; i11 < R; i11 = i11 + 1)
        a1_lanes[i11*(SW+LW) +: SW+LW] <= t2[i11];
end

reg [SW+LW-1:0] t3;
reg [SW+LW-1:0] tq [0:2*R-2];  // heap order: node n's children are 2n + 1 and 2n + 2, leaves last
generate
    if (R == 4) begin : g_t3_four
        always @* t3 = pick4(a1_lanes[0 +: SW+LW], a1_lanes[SW+LW +: SW+LW], a1_lanes[2*(SW+LW) +: SW+LW],
                             a1_lanes[3*(SW+LW) +: SW+LW]);
    end else begin : g_t3_tree
        always @* begin
            for (i5 = 0; i5 < R; i5 = i5 + 1)
                tq[R - 1 + i5] = a1_lanes[i5*(SW+LW) +: SW+LW];
            for (i5 = R - 2; i5 >= 0; i5 = i5 - 1)
                tq[i5] = pick(tq[2*i5 + 1], tq[2*i5 + 2]);
            t3 = tq[0];
        end
    end
endgenerate
reg                   a2_valid = 1'b0;
reg [TAG_W-1:0]       a2_tag;
reg [SW+LW-1:0]       a2_min;  // the group's {least sum, its lane}
always @(posedge clk) begin
    a2_valid <= a1_valid && !rst;
    a2_tag <= a1_tag;
    a2_min <= {a1_tag[TAG_W-1] ? t3[SW+LW-1:LW] : BIG, t3[LW-1:0]};
end
wire [1:0]            a2_group = a2_tag[1:0];
wire [10:0]           a2_x = a2_tag[12:2];
wire [10:0]           a2_y = a2_tag[23:13];
wire                  a2_buf = a2_tag[24];
reg [SW-1:0]          run_min;
reg [6:0]             run_d;
reg                   d_valid = 1'b0;  // a pixel's d1 and S1 are ready
reg [10:0]            d_x, d_y;
reg                   d_buf;
always @(posedge clk) begin
    d_valid <= 1'b0;
    if (a2_valid && !rst) begin
        if (a2_group == 0 || a2_min[SW+LW-1:LW] < run_min) begin
            run_min <= a2_min[SW+LW-1:LW];
            run_d <= a2_group * PARALLEL + a2_min[LW-1:0];
        end
        if (a2_group == G - 1) begin
            d_valid <= 1'b1;
            d_x <= a2_x;
            d_y <= a2_y;
            d_buf <= a2_buf;
        end
    end
end

// ---- second pass: S2 and the neighbours' sums, one group a clock
reg [2:0]             p_step = 3'd4;   // 0..3: group read now; 4: idle
reg [SW-1:0]          p_s1;
reg [6:0]             p_d1;
reg                   p_a_ok, p_b_ok;  // d1 - 1 and d1 + 1 exist (0 <= d < MAX_DISP)
reg [6:0]             p_a_at, p_b_at;  // d1 - 1, d1 + 1: the group above LW bits, the lane below
reg [10:0]            p_x, p_y;
reg                   p_buf;
wire [PARALLEL*SW-1:0] p_row = p_buf ? buf1[p_step[1:0]] : buf0[p_step[1:0]];
wire                  p_group_ok = {9'd0, p_step[1:0]} * PAR11 < {3'd0, num_disp};

reg                   b0_valid = 1'b0, b0_last = 1'b0;
reg [PARALLEL*SW-1:0] b0_lanes;          // masked
// S(d1 - 1) and S(d1 + 1) in two steps: the block of BL lanes holding each here, the lane in the
// next stage (one 32-way choice after the buffer's read, or alone in a clock, was a path at the
// period's floor)
localparam BL = (PARALLEL >= 8) ? 8 : PARALLEL;  // lanes a block
localparam LB = $clog2(BL);
reg [BL*SW-1:0]       b0_a_blk, b0_b_blk;    // the blocks of d1 - 1 and d1 + 1
reg [LB-1:0]          b0_a_lane, b0_b_lane;  // their lanes in the block
reg                   b0_has_a, b0_has_b;
always @(posedge clk) begin
    b0_valid <= 1'b0;
    b0_last <= 1'b0;
    if (p_step != 3'd4 && !rst) begin  // this clock's group of the pixel in p_*
        b0_valid <= 1'b1;
        b0_last <= p_step == 3'd3;
        b0_has_a <= 1'b0;
        b0_has_b <= 1'b0;
        // the lanes of d1 - 1, d1 and d1 + 1 in this group are left out, and a group at or above
        // num_disp whole (lane tests for equality: comparing each lane's d with d1 +- 1 was two
        // magnitude comparators a lane)
        for (i7 = 0; i7 < PARALLEL; i7 = i7 + 1) begin
            b0_lanes[i7*SW +: SW] <= (p_group_ok
                                      && !(p_step[1:0] == p_d1[LW+1:LW] && i7 == p_d1[LW-1:0])
                                      && !(p_a_ok && p_step[1:0] == p_a_at[LW+1:LW] && i7 == p_a_at[LW-1:0])
                                      && !(p_b_ok && p_step[1:0] == p_b_at[LW+1:LW] && i7 == p_b_at[LW-1:0]))
                                     ? p_row[i7*SW +: SW] : BIG;
        end
        // S(d1 - 1) and S(d1 + 1): one lane each of the group's sums, kept whole here and chosen
        // in the next stage by lanes registered here (the buffer's read and the 32-way choice
        // in one clock were a path over the period)
        for (i12 = 0; i12 < PARALLEL / BL; i12 = i12 + 1) begin
            if (p_a_at[LW-1:0] / BL == i12) b0_a_blk <= p_row[i12*BL*SW +: BL*SW];
            if (p_b_at[LW-1:0] / BL == i12) b0_b_blk <= p_row[i12*BL*SW +: BL*SW];
        end
        b0_a_lane <= p_a_at[LB-1:0];
        b0_b_lane <= p_b_at[LB-1:0];
        if (p_a_ok && p_step[1:0] == p_a_at[LW+1:LW]) begin
            b0_has_a <= 1'b1;
        end
        if (p_b_ok && p_step[1:0] == p_b_at[LW+1:LW]) begin
            b0_has_b <= 1'b1;
        end
    end
    if (rst) begin
        p_step <= 3'd4;
    end else if (d_valid) begin  // the next pixel may start in the clock of the last group's step
        p_step <= 3'd0;
        p_s1 <= run_min;
        p_d1 <= run_d;
        p_a_ok <= run_d != 7'd0;
        p_a_at <= run_d - 7'd1;
        p_b_ok <= run_d != MAX_DISP - 1;
        p_b_at <= run_d + 7'd1;
        p_x <= d_x;
        p_y <= d_y;
        p_buf <= d_buf;
    end else if (p_step != 3'd4) begin
        p_step <= (p_step == 3'd3) ? 3'd4 : p_step + 3'd1;
    end
end

// the same tree for the runner-up's minimum: PARALLEL -> R in this stage, R -> 1 in the next (b1),
// the running minimum over the groups in the one after (b2)
reg [SW-1:0] u1 [0:R1-1];
reg [SW-1:0] u2 [0:R-1];
reg [SW-1:0] u3;
always @* begin
    for (i8 = 0; i8 < R1; i8 = i8 + 1)
        u1[i8] = sc_min4(b0_lanes[(4*i8)*SW +: SW], b0_lanes[(4*i8+1)*SW +: SW], b0_lanes[(4*i8+2)*SW +: SW],
                      b0_lanes[(4*i8+3)*SW +: SW]);
end
generate
    if (R1 >= 2) begin : g_u2_pairs
        always @* begin
            for (i9 = 0; i9 < R; i9 = i9 + 1)
                u2[i9] = (u1[2*i9+1] < u1[2*i9]) ? u1[2*i9+1] : u1[2*i9];
        end
    end else begin : g_u2_same
        always @* u2[0] = u1[0];
    end
endgenerate
reg                   b1_valid = 1'b0, b1_last = 1'b0;
reg [R*SW-1:0]        b1_lanes;
reg [SW-1:0]          b1_a, b1_b;
reg                   b1_has_a, b1_has_b;
integer i6;
always @(posedge clk) begin
    b1_valid <= b0_valid && !rst;
    b1_last <= b0_last;
    for (i13 = 0; i13 < BL; i13 = i13 + 1) begin
        if (b0_a_lane == i13) b1_a <= b0_a_blk[i13*SW +: SW];
        if (b0_b_lane == i13) b1_b <= b0_b_blk[i13*SW +: SW];
    end
    b1_has_a <= b0_valid && b0_has_a;
    b1_has_b <= b0_valid && b0_has_b;
    for (i6 = 0; i6 < R; i6 = i6 + 1)
        b1_lanes[i6*SW +: SW] <= u2[i6];
end
integer i10;
generate
    if (R == 4) begin : g_u3_four
        always @* u3 = sc_min4(b1_lanes[0 +: SW], b1_lanes[SW +: SW], b1_lanes[2*SW +: SW], b1_lanes[3*SW +: SW]);
    end else begin : g_u3_chain
        always @* begin
            u3 = b1_lanes[0 +: SW];
            for (i10 = 1; i10 < R; i10 = i10 + 1)
                u3 = (b1_lanes[i10*SW +: SW] < u3) ? b1_lanes[i10*SW +: SW] : u3;
        end
    end
endgenerate
reg                   b2_valid = 1'b0, b2_last = 1'b0;
reg [SW-1:0]          b2_min, b2_a, b2_b;
reg                   b2_has_a, b2_has_b;
always @(posedge clk) begin
    b2_valid <= b1_valid && !rst;
    b2_last <= b1_last;
    b2_min <= u3;
    b2_a <= b1_a;
    b2_b <= b1_b;
    b2_has_a <= b1_valid && b1_has_a;
    b2_has_b <= b1_valid && b1_has_b;
end
reg [SW-1:0] s2_run;
reg [SW-1:0] nb_a, nb_b;
reg          c_valid = 1'b0;
reg          b2_first = 1'b1;  // the next b2 group is a pixel's first
always @(posedge clk) begin
    c_valid <= 1'b0;
    if (b2_valid && b2_has_a) nb_a <= b2_a;  // with the groups' minima: a pixel's last group
    if (b2_valid && b2_has_b) nb_b <= b2_b;  // is in the clock before the next pixel's first
    if (rst) begin
        b2_first <= 1'b1;
    end else if (b2_valid) begin
        s2_run <= (b2_first || b2_min < s2_run) ? b2_min : s2_run;
        b2_first <= b2_last;
        c_valid <= b2_last;
    end
end

// ---- arithmetic: the operands (c), then the dividers, one restoring step per clock each
// (the sub-pixel division has 4 quotient bits, the confidence 9: both run 9 stages, the first
// one idles through its last 5 so the results leave together)
localparam NUMW = 16;  // |16 (a - b) + den| <= 16 * 765 + 1531
reg          e_valid = 1'b0;
reg [NUMW-1:0] e_num_abs;
reg          e_num_neg;
reg [12:0]   e_den2;    // 2 den <= 3062
reg          e_refine;  // subpixel and 0 < d1 < num_disp - 1
reg [17:0]   e_cnum;    // (S2 - S1) * 256
reg [SW-1:0] e_s2;
reg          e_unique;
reg [6:0]    e_d1;
reg [10:0]   e_x, e_y;
// The pixel's d1, S1 and place, kept from its second pass's last step (p_* may take the next
// pixel's in that clock).
reg [SW-1:0] h_s1;
reg [6:0]    h_d1;
reg [10:0]   h_x, h_y;
// The uniqueness test's product S1 (256 + uniqueness), made with h_s1 (`uniqueness` changes only
// between frames): from the register through the multiplier and the comparison in one clock was
// the core's third longest path.
reg [8:0]    h_factor;
reg [SW+8:0] h_prod;
always @(posedge clk) begin
    h_factor <= `SC_UNIQUENESS_ONE + uniqueness;
    if (p_step == 3'd3) begin
        h_prod <= p_s1 * h_factor;
        h_s1 <= p_s1;
        h_d1 <= p_d1;
        h_x <= p_x;
        h_y <= p_y;
    end
end
// One stage (f) for the sub-pixel operands: den and 16 (a - b), with the pixel's values copied
// beside them (s2_run and nb_* take the next pixel's from the next clock; h_* four clocks later);
// the numerator's sum, its sign and magnitude a stage later (e): from nb_* through den into the
// magnitude in one clock was a path over the period.
wire [SW:0]  sum_ab = nb_a + nb_b;
wire [SW+1:0] den_raw = sum_ab - {h_s1, 1'b0};
wire [SW+1:0] den = (sum_ab <= {h_s1, 1'b0}) ? 1 : den_raw;
reg              f_valid = 1'b0;
reg [SW+1:0]     f_den;
reg signed [NUMW:0] f_d16;  // 16 (a - b)
reg [SW-1:0]     f_s1, f_s2;
reg [SW+8:0]     f_prod;
reg [6:0]        f_d1;
reg [10:0]       f_x, f_y;
always @(posedge clk) begin
    f_valid <= c_valid && !rst;
    f_den <= den;
    f_d16 <= $signed({1'b0, nb_a, 4'b0}) - $signed({1'b0, nb_b, 4'b0});
    f_s1 <= h_s1;
    f_s2 <= s2_run;
    f_prod <= h_prod;
    f_d1 <= h_d1;
    f_x <= h_x;
    f_y <= h_y;
end
wire signed [NUMW:0] num = f_d16 + $signed({1'b0, f_den});
always @(posedge clk) begin
    e_valid <= f_valid && !rst;
    e_num_neg <= num < 0;
    e_num_abs <= (num < 0) ? -num : num;
    e_den2 <= {f_den, 1'b0};
    e_refine <= subpixel && f_d1 > 0 && f_d1 + 1 < num_disp;
    e_cnum <= {f_s2 - f_s1, 8'b0};
    e_s2 <= f_s2;
    e_unique <= {f_s2, 8'b0} > f_prod;
    e_d1 <= f_d1;
    e_x <= f_x;
    e_y <= f_y;
end

localparam STAGES = 9;
reg              v_valid [0:STAGES];
reg [NUMW-1:0]   v_rem1  [0:STAGES];
reg [3:0]        v_q1    [0:STAGES];
reg [17:0]       v_rem2  [0:STAGES];
reg [8:0]        v_q2    [0:STAGES];
reg [12:0]       v_den2  [0:STAGES];
reg [SW-1:0]     v_s2    [0:STAGES];
reg              v_neg   [0:STAGES];
reg              v_refine[0:STAGES];
reg              v_unique[0:STAGES];
reg [6:0]        v_d1    [0:STAGES];
reg [10:0]       v_x     [0:STAGES];
reg [10:0]       v_y     [0:STAGES];
always @* begin
    v_valid[0] = e_valid;
    v_rem1[0] = e_num_abs;
    v_q1[0] = 4'd0;
    v_rem2[0] = e_cnum;
    v_q2[0] = 9'd0;
    v_den2[0] = e_den2;
    v_s2[0] = e_s2;
    v_neg[0] = e_num_neg;
    v_refine[0] = e_refine;
    v_unique[0] = e_unique;
    v_d1[0] = e_d1;
    v_x[0] = e_x;
    v_y[0] = e_y;
end
genvar k;
generate
    for (k = 0; k < STAGES; k = k + 1) begin : g_div
        // divider 1: quotient bit 3 - k for k < 4; divider 2: quotient bit 8 - k
        wire [NUMW+4:0] sub1 = {5'b0, v_den2[k]} << (k < 4 ? 3 - k : 0);
        wire [26:0]     sub2 = {9'b0, v_s2[k]} << (8 - k);
        always @(posedge clk) begin
            v_valid[k+1] <= v_valid[k] && !rst;
            v_den2[k+1] <= v_den2[k];
            v_s2[k+1] <= v_s2[k];
            v_neg[k+1] <= v_neg[k];
            v_refine[k+1] <= v_refine[k];
            v_unique[k+1] <= v_unique[k];
            v_d1[k+1] <= v_d1[k];
            v_x[k+1] <= v_x[k];
            v_y[k+1] <= v_y[k];
            if (k < 4 && {5'b0, v_rem1[k]} >= sub1) begin
                v_rem1[k+1] <= v_rem1[k] - sub1[NUMW-1:0];
                v_q1[k+1] <= v_q1[k] | (4'd1 << (3 - k));
            end else begin
                v_rem1[k+1] <= v_rem1[k];
                v_q1[k+1] <= v_q1[k];
            end
            if ({9'b0, v_rem2[k]} >= sub2) begin
                v_rem2[k+1] <= v_rem2[k] - sub2[17:0];
                v_q2[k+1] <= v_q2[k] | (9'd1 << (8 - k));
            end else begin
                v_rem2[k+1] <= v_rem2[k];
                v_q2[k+1] <= v_q2[k];
            end
        end
    end
endgenerate

wire [11:0] base = {v_d1[STAGES], 4'b0};
always @(posedge clk) begin
    r_valid <= v_valid[STAGES] && !rst;
    r_x <= v_x[STAGES];
    r_y <= v_y[STAGES];
    r_d1 <= v_d1[STAGES];
    r_code <= !v_refine[STAGES] ? base[10:0]
            : v_neg[STAGES] ? base[10:0] - v_q1[STAGES] : base[10:0] + v_q1[STAGES];
    r_conf <= (v_s2[STAGES] == 0) ? 8'd0 : (v_q2[STAGES] > 9'd255) ? 8'd255 : v_q2[STAGES][7:0];
    r_unique <= v_unique[STAGES];
    r_border <= v_x[STAGES] < v_d1[STAGES];
end

// ---------------------------------------------------------------- the right winners
// The cells, a group's PARALLEL at a time: cell k = PARALLEL g + j is lane j of group g's word.
// The words turn round a ring of G registers, one place per group that arrives, so the group a
// pixel brings always meets its own word in cw[0] (no multiplexer over the groups): the group is
// shifted by one cell as it is updated (cell k takes cell k - 1 as it was after the previous
// pixel: lane j takes lane j - 1 of the same word, lane 0 the last lane of the word before, kept
// from the clock that group passed) and written back at the ring's end. So one set of PARALLEL
// comparators does what a cell each did.
localparam CW = SW + 7;  // a cell: {sum, d}
localparam [CW-1:0] EMPTY = {BIG, 7'd0};
reg [PARALLEL*CW-1:0] cw [0:G-1];  // cw[0]: the word of the group arriving next
reg [CW-1:0]          carry;       // the last cell of the word before, as it was
reg [10:0]   x_now;          // the column of the pixel whose groups arrive
reg [AW-1:0] base_now;       // its row's bank

// the arriving group registered, with what its lanes' tests need (a clock for timing: the column
// tests and the comparison behind them were one long path from the front's registers)
reg                   q_valid = 1'b0;
reg [1:0]             q_group;
reg [PARALLEL*SW-1:0] q_sum;
reg                   q_row_start;      // the pixel is a row's first: its cells start empty
reg [PARALLEL-1:0]    q_lane_ok;        // lane j's cell takes part: k <= x and k < num_disp
reg [10:0]            q_x, q_y;
integer k1;
// lane j's d = PARALLEL g + j is at most x iff j <= x - PARALLEL g: one subtraction for all lanes
wire signed [12:0] s_xs = $signed({2'b00, s_x}) - $signed({2'b00, {9'd0, s_group} * PAR11});
always @(posedge clk) begin
    q_valid <= s_valid && !rst;
    q_group <= s_group;
    q_sum <= s_sum;
    q_row_start <= s_x == 11'd0;
    q_x <= s_x;
    q_y <= s_y;
    for (k1 = 0; k1 < PARALLEL; k1 = k1 + 1)
        q_lane_ok[k1] <= s_group_ok && s_xs >= k1;
end

reg [PARALLEL*CW-1:0] upd;
reg [CW-1:0]          shifted_in;
reg [6:0]             lane_d;
integer k2;
always @* begin
    for (k2 = 0; k2 < PARALLEL; k2 = k2 + 1) begin
        // (an empty cell's d is never read: every cell that leaves or is flushed has taken its
        // column's d = 0 at place 0, so only the sum is made empty)
        shifted_in = k2 == 0 ? carry : cw[0][(k2-1)*CW +: CW];
        if (q_row_start || (k2 == 0 && q_group == 2'd0)) begin
            shifted_in[CW-1:7] = BIG;
        end
        lane_d = q_group * PARALLEL + k2;
        upd[k2*CW +: CW] = (q_lane_ok[k2] && q_sum[k2*SW +: SW] < shifted_in[CW-1:7])
                         ? {q_sum[k2*SW +: SW], lane_d} : shifted_in;
    end
end

// the cell leaving the array at a shift: the last cell of the last group's word, column x - MAX_DISP
reg          ex_en = 1'b0;
reg [10:0]   ex_xr;
reg [AW-1:0] ex_base;
reg [6:0]    ex_d;

integer k4;
always @(posedge clk) begin
    ex_en <= 1'b0;
    // (the words are reset, so that no tool folds the ring's untapped sums into shift-register
    // LUTs: 310 of them)
    if (rst) begin
        for (k4 = 0; k4 < G; k4 = k4 + 1) cw[k4] <= {PARALLEL{EMPTY}};
    end else if (q_valid) begin
        for (k4 = 0; k4 < G - 1; k4 = k4 + 1) cw[k4] <= cw[k4+1];
        cw[G-1] <= upd;
    end
    if (q_valid) begin
        carry <= cw[0][(PARALLEL-1)*CW +: CW];
        if (q_group == 2'd0) begin
            x_now <= q_x;
            base_now <= bank_base(q_y);
        end
        if (q_group == G - 1) begin
            ex_en <= q_x >= MAX_DISP;
            ex_xr <= q_x - MAX_DISP;
            ex_base <= base_now;
            ex_d <= cw[0][(PARALLEL-1)*CW +: 7];
        end
    end
    if (rst) begin
        ex_en <= 1'b0;
    end
end

// the flush buffer: a finished row's winners, written out one a clock
reg [6:0]    fl_d [0:MAX_DISP-1];
reg [10:0]   fl_left = 11'd0;   // entries still to write (cell index fl_left - 1 next)
reg [10:0]   fl_x0;             // the column of cell 0 when copied
reg [AW-1:0] fl_base;

// a row's last group: every cell of the row is final; copy them the clock after (updates done)
reg last_in = 1'b0;
integer k3;
always @(posedge clk) begin
    last_in <= q_valid && q_group == G - 1 && q_x == width - 1 && !rst;
end

always @(posedge clk) begin
    w_en <= 1'b0;
    if (rst) begin
        fl_left <= 11'd0;
    end else if (last_in) begin
        for (k3 = 0; k3 < MAX_DISP; k3 = k3 + 1) fl_d[k3] <= cw[k3 / PARALLEL][(k3 % PARALLEL)*CW +: 7];
        fl_left <= (x_now + 1 < MAX_DISP) ? x_now + 11'd1 : MAX_DISP;
        fl_x0 <= x_now;
        fl_base <= base_now;
    end
    if (!rst && ex_en) begin
        w_en <= 1'b1;
        w_addr <= ex_base + ex_xr;
        w_d <= ex_d;
    end else if (!rst && !last_in && fl_left != 0) begin
        w_en <= 1'b1;
        w_addr <= fl_base + (fl_x0 - (fl_left - 11'd1));
        w_d <= fl_d[fl_left - 1];
        fl_left <= fl_left - 11'd1;
    end
end

endmodule

`resetall
