// Language: Verilog 2005

`include "prelude.vh"

`include "camera_in_spec.vh"

/*
 * camera_in: the stereocam camera input IP (stereocam/overlays/spec/camera_in.py, stereocam/overlays/rtl/camera/README.md).
 *
 * Two MT9V034 parallel receivers (ci_rx, each in its own PIXCLK domain) write whole lines into
 * their line FIFOs (ci_lfifo: a gray pointer in single steps into aclk, a handshake back). On aclk the pairing logic takes a
 * line from both FIFOs when both hold one and the two agree (same frame tag, same length), runs
 * it past two line buffers per camera (one block RAM, both cameras side by side), builds each
 * camera's 3x3 neighbourhood with mirrored borders, demosaics it (ci_demosaic) and packs both
 * cameras' RGBY into one 64-bit beat (spec/pixel.py). The AXI4-Stream master carries TUSER on
 * the first beat of a frame and TLAST on the last beat of every line, and honours TREADY: a step
 * starts only when the output FIFO has room for it and every step before it (credits), and a step
 * that reads the FIFOs only when both show a word (the words of a line appear one per pixel clock).
 *
 * Rows: input row 0 fills the line buffers; while input row y + 1 is taken, output row y is made
 * (row 0 with row 1 mirrored above it); when both cameras' FRAME_VALID have fallen (their EOF
 * records), the last row is made from the line buffers alone (row H - 2 mirrored below it). Per
 * line, WIDTH steps take the samples and one more makes the last column (column W - 2 mirrored).
 *
 * Disagreement and loss (spec/camera_in.py, "What reaches the stream"): the frame ends at the
 * first line the cameras disagree on, or at a receiver's EOF with err; its rows so far are emitted
 * as a complete shorter frame, and records are skipped until both cameras start a new frame with
 * the same tag. frames_out_reg / frames_cut_reg count emitted frames and frames cut or dropped
 * (no port: visible in simulation).
 *
 * Latency: a beat reaches m_axis 8 aclk clocks after the step that completes its neighbourhood
 * (output FIFO empty); output row y starts 4-5 aclk clocks after the header of input row y + 1 is
 * visible in both FIFOs (a FIFO publishes a committed line a word per pixel clock, header first, and
 * the pointer crosses two synchronisers), and the last row after both EOFs.
 * Throughput: one beat per aclk clock while the words are there; a line within a sensor line time.
 *
 * Reset: aresetn (aclk, active low, synchronous) resets the aclk side and, through synchronisers,
 * each receiver (whose pixel clock must run for it to take effect); the FIFOs are emptied by
 * moving their read pointers, never by clearing pointers across clock domains.
 */
module camera_in #
(
    parameter MAX_WIDTH = 752,
    parameter BAYER_PHASE = `CI_BAYER_PHASE
)
(
    input  wire                  cam0_pclk,
    input  wire [`CI_RAW_W-1:0]  cam0_data,
    input  wire                  cam0_line_valid,
    input  wire                  cam0_frame_valid,

    input  wire                  cam1_pclk,
    input  wire [`CI_RAW_W-1:0]  cam1_data,
    input  wire                  cam1_line_valid,
    input  wire                  cam1_frame_valid,

    input  wire                  aclk,
    input  wire                  aresetn,

    output wire [63:0]           m_axis_tdata,
    output wire                  m_axis_tvalid,
    input  wire                  m_axis_tready,
    output wire                  m_axis_tuser,
    output wire                  m_axis_tlast
);

localparam AW = $clog2(2 * MAX_WIDTH + 8);         // line FIFO: 2**AW words (spec.line_fifo_depth)
localparam LW = `CI_LEN_W;
localparam TW = `CI_TAG_W;
localparam RW = `CI_RAW_W;
localparam KW = `CI_REC_KIND_W;
localparam LBAW = $clog2(MAX_WIDTH);
localparam ODEPTH = `CI_OUTPUT_FIFO_DEPTH;
localparam OCW = $clog2(ODEPTH + 1);
localparam integer MAX_LEN_I = MAX_WIDTH;
localparam integer MIN_LEN_I = `CI_MIN_WIDTH;
localparam [LW-1:0] MAX_LEN = MAX_LEN_I[LW-1:0];
localparam [LW-1:0] MIN_LEN = MIN_LEN_I[LW-1:0];
localparam [KW-1:0] K_LINE = `CI_REC_LINE;
localparam [KW-1:0] K_EOF = `CI_REC_EOF;
localparam R_COL = BAYER_PHASE % 2;                 // red's column and row inside each 2x2 cell
localparam R_ROW = BAYER_PHASE / 2;

/*
 * Reset, frame tags, synchronisers
 */
reg rst_reg = 1'b1;

always @(posedge aclk) begin
    rst_reg <= !aresetn;
end

wire rst0, rst1, fv0, fv1, fv0_a, fv1_a;

ci_sync #(.INIT(1'b1)) rst0_sync_inst (.clk(cam0_pclk), .in(rst_reg), .out(rst0));
ci_sync #(.INIT(1'b1)) rst1_sync_inst (.clk(cam1_pclk), .in(rst_reg), .out(rst1));
ci_sync fv0_sync_inst (.clk(aclk), .in(fv0), .out(fv0_a));
ci_sync fv1_sync_inst (.clk(aclk), .in(fv1), .out(fv1_a));

// the tag counts the starts of vertical blanking (both FRAME_VALIDs low), in gray code
reg          both_low_reg = 1'b1;
reg [TW-1:0] tag_bin_reg = {TW{1'b0}};
reg [TW-1:0] tag_gray_reg = {TW{1'b0}};

wire          both_low = !fv0_a && !fv1_a;
wire [TW-1:0] tag_next = tag_bin_reg + 1'b1;

always @(posedge aclk) begin
    both_low_reg <= both_low;
    if (both_low && !both_low_reg) begin
        tag_bin_reg <= tag_next;
        tag_gray_reg <= tag_next ^ (tag_next >> 1);
    end
end

/*
 * Receivers and line FIFOs
 */
wire             w_en0, w_en1;
wire [AW-1:0]    w_addr0, w_addr1;
wire [`CI_REC_W-1:0] w_data0, w_data1;
wire [AW:0]      w_commit0, w_commit1, w_rptr0, w_rptr1;
wire             r_en0, r_en1, avail0, avail1;
wire [`CI_REC_W-1:0] r_data0, r_data1;

ci_rx #(.MAX_WIDTH(MAX_WIDTH), .AW(AW)) rx0_inst (
    .pclk(cam0_pclk), .rst(rst0),
    .data(cam0_data), .line_valid(cam0_line_valid), .frame_valid(cam0_frame_valid),
    .tag_gray(tag_gray_reg), .fv(fv0),
    .w_en(w_en0), .w_addr(w_addr0), .w_data(w_data0), .w_commit(w_commit0), .w_rptr(w_rptr0)
);

ci_rx #(.MAX_WIDTH(MAX_WIDTH), .AW(AW)) rx1_inst (
    .pclk(cam1_pclk), .rst(rst1),
    .data(cam1_data), .line_valid(cam1_line_valid), .frame_valid(cam1_frame_valid),
    .tag_gray(tag_gray_reg), .fv(fv1),
    .w_en(w_en1), .w_addr(w_addr1), .w_data(w_data1), .w_commit(w_commit1), .w_rptr(w_rptr1)
);

ci_lfifo #(.WIDTH(`CI_REC_W), .AW(AW)) fifo0_inst (
    .wclk(cam0_pclk), .w_en(w_en0), .w_addr(w_addr0), .w_data(w_data0), .w_commit(w_commit0), .w_rptr(w_rptr0),
    .rclk(aclk), .r_flush(rst_reg), .r_en(r_en0), .r_data(r_data0), .r_avail(avail0)
);

ci_lfifo #(.WIDTH(`CI_REC_W), .AW(AW)) fifo1_inst (
    .wclk(cam1_pclk), .w_en(w_en1), .w_addr(w_addr1), .w_data(w_data1), .w_commit(w_commit1), .w_rptr(w_rptr1),
    .rclk(aclk), .r_flush(rst_reg), .r_en(r_en1), .r_data(r_data1), .r_avail(avail1)
);

/*
 * Pairing: record heads, skipping, the frame and line sequencer
 */
localparam [1:0] ST_SEEK = 2'd0, ST_WAIT = 2'd1, ST_LINE = 2'd2, ST_FLUSH = 2'd3;
localparam [1:0] M_FIRST = 2'd0, M_SECOND = 2'd1, M_NORMAL = 2'd2, M_FLUSH = 2'd3;

reg [1:0]            state_reg = ST_SEEK;
reg [1:0]            mode_reg = M_FIRST;
reg [`CI_REC_W-1:0]  hd0_reg, hd1_reg;
reg                  hv0_reg = 1'b0, hv1_reg = 1'b0;     // a record head is held
reg                  fe0_reg = 1'b0, fe1_reg = 1'b0;     // a head is being fetched
reg [LW-1:0]         skip0_reg = {LW{1'b0}}, skip1_reg = {LW{1'b0}};
reg [LW-1:0]         width_reg = {LW{1'b0}};
reg [LW-1:0]         step_reg = {LW{1'b0}};
reg [TW-1:0]         ftag_reg = {TW{1'b0}};
reg [1:0]            rows_reg = 2'd0;                    // input rows taken, saturating at 2
reg                  rpar_reg = 1'b0;                    // parity of the next input row's index
reg [15:0]           frames_out_reg = 16'd0;
reg [15:0]           frames_cut_reg = 16'd0;
reg [4:0]            inflight_reg = 5'd0;                // steps issued whose beat is not in the FIFO yet
wire [OCW-1:0]       ocount;

wire [KW-1:0] k0 = hd0_reg[`CI_REC_W-1 -: KW];
wire [KW-1:0] k1 = hd1_reg[`CI_REC_W-1 -: KW];
wire          f0 = hd0_reg[LW + TW];                     // LINE: first; EOF: err
wire          f1 = hd1_reg[LW + TW];
wire [TW-1:0] t0 = hd0_reg[LW +: TW];
wire [TW-1:0] t1 = hd1_reg[LW +: TW];
wire [LW-1:0] n0 = hd0_reg[LW-1:0];
wire [LW-1:0] n1 = hd1_reg[LW-1:0];

wire first0 = hv0_reg && k0 == K_LINE && f0;
wire first1 = hv1_reg && k1 == K_LINE && f1;
wire [TW-1:0] tag_gap = t1 - t0;
wire behind0 = tag_gap != {TW{1'b0}} && !tag_gap[TW-1];   // t1 - t0 in 1 .. 2**(TW-1) - 1
wire agree = n0 == n1 && n0 >= MIN_LEN && n0 <= MAX_LEN;
// a frame whose partner never came: the tag has moved on (that frame is over on both cameras) and
// the other camera has nothing at all (its first line would have been visible a line time ago)
wire idle0 = !hv0_reg && !fe0_reg && !avail0 && skip0_reg == {LW{1'b0}};
wire idle1 = !hv1_reg && !fe1_reg && !avail1 && skip1_reg == {LW{1'b0}};
wire stale0 = first0 && idle1 && t0 != tag_bin_reg;
wire stale1 = first1 && idle0 && t1 != tag_bin_reg;

wire next_line = k0 == K_LINE && k1 == K_LINE && !f0 && !f1 && t0 == ftag_reg && t1 == ftag_reg
                 && n0 == width_reg && n1 == width_reg;
wire both_eof = k0 == K_EOF && k1 == K_EOF && t0 == ftag_reg && t1 == ftag_reg;

wire heads = state_reg == ST_SEEK || state_reg == ST_WAIT;
wire fetch0 = heads && !hv0_reg && !fe0_reg && skip0_reg == {LW{1'b0}} && avail0;
wire fetch1 = heads && !hv1_reg && !fe1_reg && skip1_reg == {LW{1'b0}} && avail1;
// every read waits for its word: a FIFO shows a line's words one by one (ci_lfifo)
wire skipping0 = skip0_reg != {LW{1'b0}} && avail0;
wire skipping1 = skip1_reg != {LW{1'b0}} && avail1;

// stepping through a line
wire         stepping = state_reg == ST_LINE || state_reg == ST_FLUSH;
wire         out_mode = mode_reg != M_FIRST;
wire [OCW:0] credit_need = {1'b0, ocount} + inflight_reg + 1'b1;
wire         credit_ok = credit_need <= ODEPTH;
wire         newcol = step_reg < width_reg;                       // a sample column (else the mirrored last)
wire         takes = mode_reg != M_FLUSH && newcol;                // the step reads both FIFOs
wire         issue = stepping && (!out_mode || credit_ok) && (!takes || (avail0 && avail1));
wire         last_step = out_mode ? step_reg == width_reg : step_reg == width_reg - 1'b1;
wire         pop = issue && takes;
wire         produce = issue && out_mode && step_reg != {LW{1'b0}};
wire         firstcol = step_reg == {{(LW - 1){1'b0}}, 1'b1};
wire         lastcol = step_reg == width_reg;
wire         ypar = !rpar_reg;                                     // parity of the output row
wire         xpar = !step_reg[0];                                  // parity of column step - 1

assign r_en0 = fetch0 || skipping0 || pop;
assign r_en1 = fetch1 || skipping1 || pop;

always @(posedge aclk) begin
    if (rst_reg) begin
        state_reg <= ST_SEEK;
        hv0_reg <= 1'b0;
        hv1_reg <= 1'b0;
        fe0_reg <= 1'b0;
        fe1_reg <= 1'b0;
        skip0_reg <= {LW{1'b0}};
        skip1_reg <= {LW{1'b0}};
    end else begin
        // heads arrive one clock after their fetch
        fe0_reg <= fetch0;
        fe1_reg <= fetch1;
        if (fe0_reg) begin
            hd0_reg <= r_data0;
            hv0_reg <= 1'b1;
        end
        if (fe1_reg) begin
            hd1_reg <= r_data1;
            hv1_reg <= 1'b1;
        end
        if (skipping0) begin
            skip0_reg <= skip0_reg - 1'b1;
        end
        if (skipping1) begin
            skip1_reg <= skip1_reg - 1'b1;
        end

        case (state_reg)
            ST_SEEK: begin
                // anything but a frame's first line is skipped
                if (hv0_reg && !first0) begin
                    hv0_reg <= 1'b0;
                    if (k0 == K_LINE) skip0_reg <= n0;
                end
                if (hv1_reg && !first1) begin
                    hv1_reg <= 1'b0;
                    if (k1 == K_LINE) skip1_reg <= n1;
                end
                if (stale0 || stale1) begin
                    frames_cut_reg <= frames_cut_reg + 1'b1;
                    if (stale0) begin
                        hv0_reg <= 1'b0;
                        skip0_reg <= n0;
                    end else begin
                        hv1_reg <= 1'b0;
                        skip1_reg <= n1;
                    end
                end
                if (first0 && first1) begin
                    if (t0 == t1 && agree) begin
                        hv0_reg <= 1'b0;
                        hv1_reg <= 1'b0;
                        width_reg <= n0;
                        ftag_reg <= t0;
                        rows_reg <= 2'd0;
                        rpar_reg <= 1'b0;
                        mode_reg <= M_FIRST;
                        step_reg <= {LW{1'b0}};
                        state_reg <= ST_LINE;
                    end else begin
                        // a frame that only one camera has, or lines that disagree: drop it
                        frames_cut_reg <= frames_cut_reg + 1'b1;
                        if (t0 == t1 || behind0) begin
                            hv0_reg <= 1'b0;
                            skip0_reg <= n0;
                        end
                        if (t0 == t1 || !behind0) begin
                            hv1_reg <= 1'b0;
                            skip1_reg <= n1;
                        end
                    end
                end
            end
            ST_WAIT: begin
                if (hv0_reg && hv1_reg) begin
                    if (next_line) begin
                        hv0_reg <= 1'b0;
                        hv1_reg <= 1'b0;
                        mode_reg <= rows_reg == 2'd1 ? M_SECOND : M_NORMAL;
                        step_reg <= {LW{1'b0}};
                        state_reg <= ST_LINE;
                    end else begin
                        // the end of the frame, or the cameras disagree: end it here
                        if (both_eof) begin
                            hv0_reg <= 1'b0;
                            hv1_reg <= 1'b0;
                        end
                        if (!both_eof || f0 || f1 || rows_reg != 2'd2) begin
                            frames_cut_reg <= frames_cut_reg + 1'b1;
                        end
                        mode_reg <= M_FLUSH;
                        step_reg <= {LW{1'b0}};
                        state_reg <= rows_reg == 2'd2 ? ST_FLUSH : ST_SEEK;
                    end
                end
            end
            default: begin  // ST_LINE, ST_FLUSH
                if (issue) begin
                    step_reg <= step_reg + 1'b1;
                    if (last_step) begin
                        if (state_reg == ST_FLUSH) begin
                            frames_out_reg <= frames_out_reg + 1'b1;
                            state_reg <= ST_SEEK;
                        end else begin
                            rows_reg <= rows_reg == 2'd2 ? 2'd2 : rows_reg + 1'b1;
                            rpar_reg <= !rpar_reg;
                            state_reg <= ST_WAIT;
                        end
                    end
                end
            end
        endcase
    end
end

/*
 * The step pipeline: P0 issue, P1 FIFO data and RAM read, P2 RAM data and line buffer write,
 * P3 the 3x3 window, P3..P7 ci_demosaic, P7 the output FIFO write.
 */
localparam CTRL_W = 11;
// control word: {valid, out_mode, newcol, produce, firstcol, lastcol, tuser, tlast, red_row, red_col, 0}
wire [1:0] mode_code = mode_reg;
wire [CTRL_W-1:0] ctrl0 = {issue, out_mode, newcol, produce, firstcol, lastcol,
                           produce && firstcol && mode_reg == M_SECOND, produce && lastcol,
                           (ypar ^ R_ROW[0]) == 1'b0, (xpar ^ R_COL[0]) == 1'b0, 1'b0};

reg [CTRL_W-1:0] ctrl1_reg = {CTRL_W{1'b0}}, ctrl2_reg = {CTRL_W{1'b0}}, ctrl3_reg = {CTRL_W{1'b0}};
reg [1:0]        mode1_reg = 2'd0, mode2_reg = 2'd0;
reg [LBAW-1:0]   addr1_reg = {LBAW{1'b0}}, addr2_reg = {LBAW{1'b0}};
reg [RW-1:0]     pix0_2_reg = {RW{1'b0}}, pix1_2_reg = {RW{1'b0}};

wire [LBAW-1:0] step_addr = step_reg[LBAW-1:0];

always @(posedge aclk) begin
    ctrl1_reg <= rst_reg ? {CTRL_W{1'b0}} : ctrl0;
    ctrl2_reg <= rst_reg ? {CTRL_W{1'b0}} : ctrl1_reg;
    ctrl3_reg <= rst_reg ? {CTRL_W{1'b0}} : ctrl2_reg;
    mode1_reg <= mode_code;
    mode2_reg <= mode1_reg;
    addr1_reg <= step_addr;
    addr2_reg <= addr1_reg;
    pix0_2_reg <= r_data0[RW-1:0];
    pix1_2_reg <= r_data1[RW-1:0];
end

// line buffers: per camera {previous row, newest row} at each column
wire [4*RW-1:0] lb_rdata;
wire [RW-1:0]   a0 = lb_rdata[0*RW +: RW];   // camera 0, the newest row taken (the output row)
wire [RW-1:0]   b0 = lb_rdata[1*RW +: RW];   // camera 0, the row before it
wire [RW-1:0]   a1 = lb_rdata[2*RW +: RW];
wire [RW-1:0]   b1 = lb_rdata[3*RW +: RW];

wire v2 = ctrl2_reg[CTRL_W-1];
wire newcol2 = ctrl2_reg[CTRL_W-3];
wire lb_we = v2 && newcol2 && mode2_reg != M_FLUSH;

rc_ram #(.WIDTH(4 * RW), .DEPTH(MAX_WIDTH), .AW(LBAW)) lb_inst (
    .clk(aclk),
    .we(lb_we), .waddr(addr2_reg), .wdata({a1, pix1_2_reg, a0, pix0_2_reg}),
    .re(issue && newcol), .raddr(step_addr), .rdata(lb_rdata)
);

// the new column of each camera's window: {above, centre, below}
reg [3*RW-1:0] col0, col1;

always @* begin
    case (mode2_reg)
        M_SECOND: begin col0 = {pix0_2_reg, a0, pix0_2_reg}; col1 = {pix1_2_reg, a1, pix1_2_reg}; end
        M_FLUSH:  begin col0 = {b0, a0, b0};                 col1 = {b1, a1, b1};                 end
        default:  begin col0 = {b0, a0, pix0_2_reg};         col1 = {b1, a1, pix1_2_reg};         end
    endcase
end

reg [3*RW-1:0] l0_reg, m0_reg, r0_reg, l1_reg, m1_reg, r1_reg;

always @(posedge aclk) begin
    if (v2 && ctrl2_reg[CTRL_W-2]) begin  // out_mode: every step shifts, the mirrored last column too
        l0_reg <= m0_reg;
        m0_reg <= r0_reg;
        l1_reg <= m1_reg;
        m1_reg <= r1_reg;
        if (newcol2) begin
            r0_reg <= col0;
            r1_reg <= col1;
        end
    end
end

wire firstcol3 = ctrl3_reg[CTRL_W-5];
wire lastcol3 = ctrl3_reg[CTRL_W-6];
wire [3*RW-1:0] left0 = firstcol3 ? r0_reg : l0_reg;
wire [3*RW-1:0] right0 = lastcol3 ? l0_reg : r0_reg;
wire [3*RW-1:0] left1 = firstcol3 ? r1_reg : l1_reg;
wire [3*RW-1:0] right1 = lastcol3 ? l1_reg : r1_reg;

// {a_l, a_m, a_r, c_l, c_m, c_r, b_l, b_m, b_r}
wire [9*RW-1:0] win0 = {left0[3*RW-1 -: RW], m0_reg[3*RW-1 -: RW], right0[3*RW-1 -: RW],
                        left0[2*RW-1 -: RW], m0_reg[2*RW-1 -: RW], right0[2*RW-1 -: RW],
                        left0[RW-1:0], m0_reg[RW-1:0], right0[RW-1:0]};
wire [9*RW-1:0] win1 = {left1[3*RW-1 -: RW], m1_reg[3*RW-1 -: RW], right1[3*RW-1 -: RW],
                        left1[2*RW-1 -: RW], m1_reg[2*RW-1 -: RW], right1[2*RW-1 -: RW],
                        left1[RW-1:0], m1_reg[RW-1:0], right1[RW-1:0]};

wire [31:0] rgby0, rgby1;

ci_demosaic dm0_inst (.clk(aclk), .win(win0), .red_row(ctrl3_reg[2]), .red_col(ctrl3_reg[1]), .rgby(rgby0));
ci_demosaic dm1_inst (.clk(aclk), .win(win1), .red_row(ctrl3_reg[2]), .red_col(ctrl3_reg[1]), .rgby(rgby1));

// the control word alongside ci_demosaic's 4 clocks
reg [CTRL_W-1:0] ctrl4_reg = {CTRL_W{1'b0}}, ctrl5_reg = {CTRL_W{1'b0}};
reg [CTRL_W-1:0] ctrl6_reg = {CTRL_W{1'b0}}, ctrl7_reg = {CTRL_W{1'b0}};

always @(posedge aclk) begin
    ctrl4_reg <= rst_reg ? {CTRL_W{1'b0}} : ctrl3_reg;
    ctrl5_reg <= rst_reg ? {CTRL_W{1'b0}} : ctrl4_reg;
    ctrl6_reg <= rst_reg ? {CTRL_W{1'b0}} : ctrl5_reg;
    ctrl7_reg <= rst_reg ? {CTRL_W{1'b0}} : ctrl6_reg;
end

wire write_out = ctrl7_reg[CTRL_W-1] && ctrl7_reg[CTRL_W-4];   // valid && produce

always @(posedge aclk) begin
    if (rst_reg) begin
        inflight_reg <= 5'd0;
    end else begin
        inflight_reg <= inflight_reg + {4'd0, produce} - {4'd0, write_out};
    end
end

/*
 * Output
 */
wire [65:0] out_word;
wire        ovalid;

// a step starts only if its beat has room (credits): the FIFO is never full when a word
// arrives, so s_ready is left open
// verilator lint_off PINCONNECTEMPTY
rc_fifo #(.WIDTH(66), .DEPTH(ODEPTH), .SHOW_AHEAD(1)) ofifo_inst (
    .clk(aclk), .rst(rst_reg),
    .s_data({ctrl7_reg[4], ctrl7_reg[3], rgby1, rgby0}), .s_valid(write_out), .s_ready(),
    .m_data(out_word), .m_valid(ovalid), .m_ready(m_axis_tready && aresetn), .count(ocount)
);
// verilator lint_on PINCONNECTEMPTY

// TVALID low from the first clock of aresetn low (rst_reg follows a clock later): no beat leaves in reset
assign m_axis_tvalid = ovalid && aresetn;

assign m_axis_tdata = out_word[63:0];
assign m_axis_tlast = out_word[64];
assign m_axis_tuser = out_word[65];

// verilator lint_off UNUSEDSIGNAL
wire unused_ok = &{1'b0, r_data0[`CI_REC_W-1:RW], r_data1[`CI_REC_W-1:RW], ctrl3_reg[0], ctrl7_reg[0],
                   ctrl7_reg[CTRL_W-2:CTRL_W-3], ctrl7_reg[CTRL_W-5:CTRL_W-6], ctrl7_reg[2:1]};
// verilator lint_on UNUSEDSIGNAL

endmodule

`resetall
