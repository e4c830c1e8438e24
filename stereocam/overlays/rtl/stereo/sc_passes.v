// Language: Verilog 2005

`include "prelude.vh"

`include "stereo_spec.vh"

/*
 * sc_passes: the stereo core's two row passes behind the winners (STEREO_CORE.md, steps 7 and 8),
 * run in lockstep with the sweeps: `run` enables a clock, a slot is 4 run clocks (`phase`), and
 * the scheduler's sweep row and column say where each pass is.
 *
 * Phase B (sweep row - 2, the slot's column): each pixel's validity in the spec's order (matched
 * outside the right image; not unique; with LR_CHECK, the right winner at x - d1 more than LR_TOL
 * away) and the code and confidence kept. Phase 0 reads the pixel's record, phase 2 the right
 * winner at x - d1 (reads take 2 run clocks), phase 0 of the next slot writes the checked code.
 * Phase C (sweep row - 3, the slot's column - LAG): the 3x3 median and the output beat. Phase B
 * writes the row below one slot behind its own column, so a lag of 4 columns leaves 2 slots
 * between that write and the read here. Each slot reads column x + 1 of the three rows around
 * (phases 0, 1, 2), shifts them into a 3x3 window at phase 1 of the next slot and hands the window
 * to the median network (5 free-running stages of two compare levels), which writes the beat.
 * RAMs: the records and right winners (written by sc_winners) are outside; the checked
 * codes inside; each banked by row mod 3 at MAX_WIDTH words a bank.
 * Out: `o_valid` one clock a pixel: o_data {5'b0, reason, conf, code}, o_user (first pixel of a
 * frame), o_last (end of a row), o_eof (the frame's last beat).
 * `frame_begin` (the first beat of a frame taken, while no slot runs) forgets the last slot's centre.
 * Reset: synchronous, active high.
 */
module sc_passes #
(
    parameter MAX_WIDTH = 752,
    parameter AW = $clog2(3 * MAX_WIDTH),
    parameter LAG = 4
)
(
    input  wire               clk,
    input  wire               rst,
    input  wire [10:0]        width,
    input  wire [10:0]        height,
    input  wire               lr_check,
    input  wire [3:0]         lr_tol,
    input  wire               median,
    input  wire               frame_begin,  // a frame's first beat is taken (between frames)
    input  wire               run,
    input  wire [1:0]         phase,
    input  wire signed [11:0] row,
    input  wire signed [11:0] col,
    input  wire [1:0]         row_bank,     // row mod 3 (where row >= 0)

    output wire               rec_re,
    output wire [AW-1:0]      rec_raddr,
    input  wire [27:0]        rec_rdata,   // {border, unique, conf[7:0], code[10:0], d1[6:0]}
    output wire               dr_re,
    output wire [AW-1:0]      dr_raddr,
    input  wire [6:0]         dr_rdata,

    output reg                o_valid = 1'b0,
    output reg  [31:0]        o_data,
    output reg                o_user,
    output reg                o_last,
    output reg                o_eof
);

`include "sc_bank.vh"

wire signed [11:0] row_b = row - 12'sd2;
wire signed [11:0] row_c = row - 12'sd3;
wire signed [11:0] x_c = col - LAG;
// the banks of row_b (row - 2 = row + 1 mod 3) and of phase C's reads (row - 4 + phase = row + 2 +
// phase mod 3); where those rows are negative nothing is read or written
wire [1:0] bank_b = bank_plus(row_bank, 2'd1);
wire [1:0] bank_c = bank_plus(row_bank, (phase == 2'd0) ? 2'd2 : (phase == 2'd1) ? 2'd0 : 2'd1);

// the checked codes: phase B writes, phase C reads
reg           code_we = 1'b0;
reg  [AW-1:0] code_waddr;
reg  [26:0]   code_wdata;   // {reason[2:0], conf[7:0], code[15:0]}
wire          code_re;
wire [AW-1:0] code_raddr;
wire [26:0]   code_rdata;
// (in 9-bit slices, a block RAM each as 4K x 9: one deep, no LUTs choosing between blocks: rc_ram)
rc_ram #(.WIDTH(27), .DEPTH(3 * MAX_WIDTH), .AW(AW), .SLICE(9)) code_ram (
    .clk(clk), .we(code_we), .waddr(code_waddr), .wdata(code_wdata),
    .re(code_re), .raddr(code_raddr), .rdata(code_rdata)
);

// ---------------------------------------------------------------- phase B: validity
// The rows' tests, a clock behind `row` (from the scheduler's row through the arithmetic and the
// comparisons into the RAM enables was a path over the period): `row` changes at a sweep's first
// slot, where `col` is still negative (-PRE), so no read or write depends on them there. The
// bounds come from registers of height + 2 .. 4 (the height changes only between frames).
reg [11:0] height2, height3, height4;
reg        row_b_in = 1'b0;     // row_b (row - 2) inside the image; also row_c + 1
reg [1:0]  row_c_in = 2'b00;    // row_c - 1 + k (row - 4 + k) inside the image, k = 0, 1
always @(posedge clk) begin
    height2 <= {1'b0, height} + 12'd2;
    height3 <= {1'b0, height} + 12'd3;
    height4 <= {1'b0, height} + 12'd4;
    row_b_in <= row >= 12'sd2 && row < $signed(height2);
    row_c_in[0] <= row >= 12'sd4 && row < $signed(height4);
    row_c_in[1] <= row >= 12'sd3 && row < $signed(height3);
end
wire real_now = row_b_in && col >= 0 && col < $signed({1'b0, width});

// phase 0: the record
reg          a_real = 1'b0;
reg [10:0]   a_x;
reg [AW-1:0] a_base;
assign rec_re = run && phase == 2'd0 && real_now;
assign rec_raddr = base_of_bank(bank_b) + col[10:0];
always @(posedge clk) begin
    if (rst) begin
        a_real <= 1'b0;
    end else if (run && phase == 2'd0) begin
        a_real <= real_now;
        a_x <= col[10:0];
        a_base <= base_of_bank(bank_b);
    end
end

// phase 2: the record arrives; the right winner's read
wire [6:0]   rec_d1 = rec_rdata[6:0];
wire [10:0]  rec_code = rec_rdata[17:7];
wire [7:0]   rec_conf = rec_rdata[25:18];
wire         rec_unique = rec_rdata[26];
wire         rec_border = rec_rdata[27];
reg          b_real = 1'b0;
reg [10:0]   b_x;
reg [AW-1:0] b_base;
reg [6:0]    b_d1;
reg [10:0]   b_code;
reg [7:0]    b_conf;
reg          b_unique, b_border;
assign dr_re = run && phase == 2'd2 && a_real && !rec_border;
assign dr_raddr = a_base + (a_x - rec_d1);
always @(posedge clk) begin
    if (rst) begin
        b_real <= 1'b0;
    end else if (run && phase == 2'd2) begin
        b_real <= a_real;
        b_x <= a_x;
        b_base <= a_base;
        b_d1 <= rec_d1;
        b_code <= rec_code;
        b_conf <= rec_conf;
        b_unique <= rec_unique;
        b_border <= rec_border;
    end
end

// phase 0 of the next slot: decide and write
wire [7:0] gap = (b_d1 > dr_rdata) ? b_d1 - dr_rdata : dr_rdata - b_d1;
reg  [2:0] reason;
always @* begin
    if (b_border) reason = `SC_REASON_BORDER;
    else if (!b_unique) reason = `SC_REASON_UNIQUENESS;
    else if (lr_check && gap > lr_tol) reason = `SC_REASON_LR;
    else reason = `SC_REASON_VALID;
end
always @(posedge clk) begin
    code_we <= 1'b0;
    if (!rst && run && phase == 2'd0 && b_real) begin
        code_we <= 1'b1;
        code_waddr <= b_base + b_x;
        code_wdata <= (reason == `SC_REASON_VALID) ? {reason, b_conf, 5'b0, b_code}
                                                   : {reason, 8'd0, 16'd`SC_INVALID};
    end
end

// ---------------------------------------------------------------- phase C: median, output
localparam CW = 27;


// ---- reads: column x_c + 1 of rows row_c - 1 + phase (phases 0..2)
wire signed [11:0] rcol = x_c + 12'sd1;
wire        row_in = (phase == 2'd0) ? row_c_in[0] : (phase == 2'd1) ? row_c_in[1] : row_b_in;
// The column's test for the `col` of the next clock, registered (from col through the arithmetic
// and the comparison into the RAM's enable was a path over the period): col advances at the end
// of a slot's phase 3 (after a sweep's last slot it goes to -PRE, but that slot's col + 1 - LAG + 1
// is past the width anyway: a sweep has at least width + 8 slots) and is -PRE after frame_begin.
// The bounds are constants and registers of width + LAG - 2, + LAG - 1 (the width changes only
// between frames), so the test is comparisons of col alone.
reg signed [11:0] width_adv, width_stay;
always @(posedge clk) begin
    width_adv <= $signed({1'b0, width}) + LAG - 2;
    width_stay <= $signed({1'b0, width}) + LAG - 1;
end
wire        advancing = run && phase == 2'd3;
reg         col_in = 1'b0;
always @(posedge clk) begin
    col_in <= !frame_begin && (advancing ? col >= LAG - 2 && col < width_adv
                                         : col >= LAG - 1 && col < width_stay);
end
assign code_re = run && phase != 2'd3 && row_in && col_in;
assign code_raddr = base_of_bank(bank_c) + rcol[10:0];

// what each read brings, 2 run clocks later: phases 2, 3 and the next slot's 0
reg [1:0] q_in;       // [0]: read 1 run clock ago, [1]: 2 run clocks ago
reg [1:0] q_slot0, q_slot1;  // their window row_c (0..2)
reg       q_ok0, q_ok1;      // inside the image
always @(posedge clk) begin
    if (rst) begin
        q_in <= 2'b00;
    end else if (run) begin
        q_in <= {q_in[0], phase != 2'd3};
        q_slot1 <= q_slot0;
        q_ok1 <= q_ok0;
        q_slot0 <= phase;
        q_ok0 <= row_in && col_in;
    end
end
reg [CW-1:0] newc [0:2];
reg          newv [0:2];
always @(posedge clk) begin
    if (run && q_in[1]) begin
        newc[q_slot1] <= code_rdata;
        newv[q_slot1] <= q_ok1;
    end
end

// ---- the window, shifted at phase 1 (all three of the column are in by then)
integer ri3, ri4, ri5, ci4;
reg [CW-1:0] win [0:2][0:2];  // [row_c][column]
reg          wv  [0:2][0:2];
reg signed [11:0] prev_x = -12'sd1, cur_x = -12'sd1, prev_row = -12'sd1, cur_row = -12'sd1;
reg          go = 1'b0;       // the window now holds a centre to filter
always @(posedge clk) begin
    go <= 1'b0;
    if (rst) begin
        go <= 1'b0;
        prev_x <= -12'sd1;
        prev_row <= -12'sd1;
    end else if (run && phase == 2'd1) begin
        for (ri3 = 0; ri3 < 3; ri3 = ri3 + 1) begin
            win[ri3][0] <= win[ri3][1];
            wv[ri3][0] <= wv[ri3][1];
            win[ri3][1] <= win[ri3][2];
            wv[ri3][1] <= wv[ri3][2];
            win[ri3][2] <= newc[ri3];
            wv[ri3][2] <= newv[ri3];
        end
        go <= 1'b1;
        cur_x <= prev_x;
        cur_row <= prev_row;
    end
    if (run && phase == 2'd3) begin
        prev_x <= x_c;    // this slot's column arrives by the next slot's phase 1: centre x_c
        prev_row <= row_c;
    end
    // The frame's first slot hands on the centre of the slot before it: none. Without this it
    // was the previous frame's last (a column and row outside that frame, which a wider or
    // taller frame takes for one of its own: a beat before the TUSER beat).
    if (frame_begin) begin
        prev_x <= -12'sd1;
        prev_row <= -12'sd1;
    end
end

// ---- the nine codes, outside ones as the centre; then the median network (Devillard's opt_med9)
// The network works on 11 bits: a code is 16 d1 + offset, at most 16 x 127 + 8 = 2040, and the
// invalid 0xFFFF becomes 2047, still above every code (five bits of every exchange fewer).
localparam VB = 11;
function [VB-1:0] narrow;
    input [15:0] code;
    begin
        narrow = code[VB-1:0] | {VB{code[15]}};
    end
endfunction
wire [VB-1:0] centre = narrow(win[1][1][15:0]);
reg  [VB-1:0] p [0:8];
always @* begin
    for (ri4 = 0; ri4 < 3; ri4 = ri4 + 1)
        for (ci4 = 0; ci4 < 3; ci4 = ci4 + 1)
            p[ri4*3+ci4] = wv[ri4][ci4] ? narrow(win[ri4][ci4][15:0]) : centre;
end

function [2*VB-1:0] srt;  // {min, max}
    input [VB-1:0] a;
    input [VB-1:0] b;
    begin
        srt = (b < a) ? {b, a} : {a, b};
    end
endfunction

// pipeline registers: s1..s5 hold the nine values (or what is left of them) and the centre's data
reg [VB-1:0] s1 [0:8];
reg [VB-1:0] s2 [0:8];
reg [VB-1:0] s3 [0:8];
reg [VB-1:0] s4 [0:8];
reg [VB-1:0] m5;
reg [CW-1:0] c1, c2, c3, c4, c5;
reg        v1 = 1'b0, v2 = 1'b0, v3 = 1'b0, v4 = 1'b0, v5 = 1'b0;
reg signed [11:0] x1 = -12'sd1, x2 = -12'sd1, x3 = -12'sd1, x4 = -12'sd1, x5 = -12'sd1;
reg signed [11:0] y1 = -12'sd1, y2 = -12'sd1, y3 = -12'sd1, y4 = -12'sd1, y5 = -12'sd1;
reg [VB-1:0] t [0:8];
reg [2*VB-1:0] o;
integer ri7;
// stage 0: the nine values registered (the substitution of the centre before stage 1's two
// exchanges in a row was a path over the period)
reg [VB-1:0] s0 [0:8];
reg [CW-1:0] c0;
reg        v0 = 1'b0;
reg signed [11:0] x0 = -12'sd1, y0 = -12'sd1;
always @(posedge clk) begin
    for (ri7 = 0; ri7 < 9; ri7 = ri7 + 1) s0[ri7] <= p[ri7];
    v0 <= go && !rst;
    c0 <= win[1][1];
    x0 <= cur_x;
    y0 <= cur_row;
end
integer ri6;
always @(posedge clk) begin
    // stage 1: sort(1,2) sort(4,5) sort(7,8); sort(0,1) sort(3,4) sort(6,7)
    for (ri6 = 0; ri6 < 9; ri6 = ri6 + 1) t[ri6] = s0[ri6];
    o = srt(t[1], t[2]); t[1] = o[2*VB-1:VB]; t[2] = o[VB-1:0];
    o = srt(t[4], t[5]); t[4] = o[2*VB-1:VB]; t[5] = o[VB-1:0];
    o = srt(t[7], t[8]); t[7] = o[2*VB-1:VB]; t[8] = o[VB-1:0];
    o = srt(t[0], t[1]); t[0] = o[2*VB-1:VB]; t[1] = o[VB-1:0];
    o = srt(t[3], t[4]); t[3] = o[2*VB-1:VB]; t[4] = o[VB-1:0];
    o = srt(t[6], t[7]); t[6] = o[2*VB-1:VB]; t[7] = o[VB-1:0];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s1[ri5] <= t[ri5];
    // stage 2: sort(1,2) sort(4,5) sort(7,8); p3 = max(0,3); p5 = min(5,8); (p6 kept)
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) t[ri5] = s1[ri5];
    o = srt(t[1], t[2]); t[1] = o[2*VB-1:VB]; t[2] = o[VB-1:0];
    o = srt(t[4], t[5]); t[4] = o[2*VB-1:VB]; t[5] = o[VB-1:0];
    o = srt(t[7], t[8]); t[7] = o[2*VB-1:VB]; t[8] = o[VB-1:0];
    t[3] = (t[0] > t[3]) ? t[0] : t[3];
    t[5] = (t[5] < t[8]) ? t[5] : t[8];
    // (stage 3's first exchange, done here: it reads only 4 and 7, which nothing after it in this
    // stage does; in stage 3 it made a chain of three, a path over the period)
    o = srt(t[4], t[7]); t[4] = o[2*VB-1:VB]; t[7] = o[VB-1:0];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s2[ri5] <= t[ri5];
    // stage 3: p6 = max(3,6); p4 = max(1,4); p2 = min(2,5); p4 = min(4,7)
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) t[ri5] = s2[ri5];
    t[6] = (t[3] > t[6]) ? t[3] : t[6];
    t[4] = (t[1] > t[4]) ? t[1] : t[4];
    t[2] = (t[2] < t[5]) ? t[2] : t[5];
    t[4] = (t[4] < t[7]) ? t[4] : t[7];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s3[ri5] <= t[ri5];
    // stage 4: sort(4,2); p4 = max(6,4)
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) t[ri5] = s3[ri5];
    o = srt(t[4], t[2]); t[4] = o[2*VB-1:VB]; t[2] = o[VB-1:0];
    t[4] = (t[6] > t[4]) ? t[6] : t[4];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s4[ri5] <= t[ri5];
    // stage 5: p4 = min(4,2): the median
    m5 <= (s4[4] < s4[2]) ? s4[4] : s4[2];

    v1 <= v0 && !rst;  v2 <= v1 && !rst;  v3 <= v2 && !rst;  v4 <= v3 && !rst;  v5 <= v4 && !rst;
    // (reset, like x and y: no tool folds these delay lines into shift-register LUTs)
    if (rst) begin
        c1 <= {CW{1'b0}};  c2 <= {CW{1'b0}};  c3 <= {CW{1'b0}};  c4 <= {CW{1'b0}};  c5 <= {CW{1'b0}};
    end else begin
        c1 <= c0;  c2 <= c1;  c3 <= c2;  c4 <= c3;  c5 <= c4;
    end
    if (rst) begin
        x1 <= -12'sd1;  x2 <= -12'sd1;  x3 <= -12'sd1;  x4 <= -12'sd1;  x5 <= -12'sd1;
        y1 <= -12'sd1;  y2 <= -12'sd1;  y3 <= -12'sd1;  y4 <= -12'sd1;  y5 <= -12'sd1;
    end else begin
        x1 <= x0;  x2 <= x1;  x3 <= x2;  x4 <= x3;  x5 <= x4;
        y1 <= y0;  y2 <= y1;  y3 <= y2;  y4 <= y3;  y5 <= y4;
    end
end

// ---- the beat
wire real5 = y5 >= 0 && y5 < $signed({1'b0, height}) && x5 >= 0 && x5 < $signed({1'b0, width});
always @(posedge clk) begin
    o_valid <= v5 && real5 && !rst;
    o_user <= x5 == 0 && y5 == 0;
    o_last <= x5 == $signed({1'b0, width}) - 12'sd1;
    o_eof <= x5 == $signed({1'b0, width}) - 12'sd1 && y5 == $signed({1'b0, height}) - 12'sd1;
    if (!median || c5[15:0] == `SC_INVALID) begin
        o_data <= {5'b0, c5};
    end else if (m5 == {VB{1'b1}}) begin
        o_data <= {5'b0, 3'd`SC_REASON_MEDIAN, 8'd0, 16'd`SC_INVALID};
    end else begin
        o_data <= {5'b0, c5[26:16], {16-VB{1'b0}}, m5};
    end
end

endmodule

`resetall
