// Language: Verilog 2005

`include "prelude.vh"

`include "rectify_spec.vh"

/*
 * rc_datapath: the rectify core's pixel side (RECTIFY_CORE.md: "Stream
 * interface", "Malformed input", step 5, "Gray of a tap", edges, "The line
 * buffer"): input checking, the line buffers, output sequencing, taps,
 * interpolation, bypass, gray, debug line and the output stream.
 *
 * Input. The AXI4-Stream slave goes through a register slice (rc_skid), then
 * the input checker takes at most one beat per clock. Beats before a TUSER
 * are discarded. A TUSER beat starts a frame when ENABLE is 1, no APPLY is
 * pending and the previous frame has been emitted completely; the active set
 * and the control bits are sampled then and hold for the frame (its TREADY
 * is low until then). Each beat is counted (column, row) and written into
 * the line buffer; an input error (TUSER not first, line short, line long,
 * or beats after the HEIGHT-th line) pulses set_size_error and ends the
 * frame's input with r complete rows; input is then discarded up to the next
 * TUSER (a TUSER that caused the error is not consumed: it starts the next
 * frame). Input row r is accepted only while r <= e(y) + 1 for the oldest
 * output row y whose reads are not complete (so row e(y) + 2 waits).
 *
 * Line buffer. Per camera LB_ROWS + 1 rows in four banks by row parity and
 * column parity (rc_linebuf; RGB 24-bit with COLOUR 1, the stream's gray
 * byte with COLOUR 0). Input row r, column c goes to bank {r[0], c[0]} at
 * address slot(r) * CW + c / 2 with slot(r) = (r / 2) mod NS, NS =
 * ceil((LB_ROWS + 1) / 2) and CW = ceil(MAX_WIDTH / 2): densely packed, a
 * bank holds NS * CW words. The rows of one parity among any LB_ROWS + 1
 * consecutive rows have NS consecutive values of r / 2, so the window of an
 * output row and the row being written never share a slot. A side buffer
 * holds the bits the line buffer does not (the gray bytes with COLOUR 1,
 * R, G, B with COLOUR 0) for two rows, for BYPASS.
 *
 * Output sequencing. e(y) = min(y + LB_DELAY, HEIGHT - 1) (e(y) = y with
 * BYPASS or before the first APPLY). Output row y is issued when input row
 * e(y) is complete; if the input ended with r <= e(0) complete rows the frame
 * is dropped, else rows with e(y) >= r are issued as zero rows (they read
 * nothing). The coordinate engine is started when row e(0) is complete (so a
 * dropped frame never starts it) and its W * H positions are all consumed,
 * one per output pixel, zero rows included. With BYPASS it is not started:
 * the position of pixel (x, y) is (32 x, 32 y), whose interpolation is G0.
 *
 * Pixel pipeline. An output pixel is issued as two items, left camera then
 * right camera on the next clock (2 clocks per pixel, the coordinate
 * engine's rate), through one shared tap and interpolation pipeline: tap
 * rows and columns, edge and window checks (LB_OVERFLOW for a valid pixel
 * with a neighbour inside the image and outside rows e(y) - LB_ROWS + 1 ..
 * e(y)), bank slots and addresses, the bank reads, per-tap gray (COLOUR 1),
 * the interpolation (rc_interp, no DSP), and the output word (GRAY, BYPASS,
 * zero rows, DEBUG_LINE last). The pipeline never stalls: a pixel is issued
 * only while the pixels in flight and the words in the output FIFO are fewer
 * than FIFO_DEPTH (credits), so the output honours TREADY without dropping
 * or repeating a beat. TUSER goes with the frame's first beat, TLAST with
 * each row's last; frame_done pulses when the frame's last beat leaves.
 *
 * Latency (clocks, as measured by tests/hdl/tb_rc_datapath.py and
 * tb_rectify_core.py): a beat on s_axis reaches the checker through the
 * register slice (1 clock); a TUSER beat starts the frame 1 clock after that.
 * The pixel pipeline is ST_OUT + 1 clocks from the issue register to the FIFO
 * (16 with COLOUR 1, 14 with COLOUR 0) and the FIFO 2 more: the first output
 * beat leaves 22 clocks (COLOUR 0: 20) after the last beat of input row e(0)
 * is accepted with BYPASS, and later by the coordinate engine's latency
 * otherwise (85 clocks in rectify_core with rc_coord's 63). Throughput:
 * 2 clocks per output beat (the coordinate engine's rate); input up to 1 beat
 * per clock while the line buffer has room. Drain: output rows whose e(y) is
 * the last input row start after it: 2 * WIDTH * (H - y) clocks for them plus
 * the pipeline (LB_DELAY 0, 64 wide: 197 clocks from the last input beat to
 * the last output beat). The next TUSER is accepted once the last beat has
 * left (idle is 1 from then until the next start).
 *
 * Reset: synchronous, active high: no frame, FIFO empty, s_axis_tready low.
 */
module rc_datapath #
(
    parameter MAX_WIDTH = 752,
    parameter MAX_HEIGHT = 1024,
    parameter LB_ROWS = 80,
    parameter COLOUR = 1,
    // output FIFO words, also the credits for pixels in flight (a power of two)
    parameter FIFO_DEPTH = 32
)
(
    input  wire                         clk,
    input  wire                         rst,

    /*
     * AXI4-Stream input (both cameras per beat, TUSER start of frame, TLAST end of line)
     */
    input  wire [63:0]                  s_axis_tdata,
    input  wire                         s_axis_tvalid,
    output wire                         s_axis_tready,
    input  wire                         s_axis_tlast,
    input  wire                         s_axis_tuser,

    /*
     * AXI4-Stream output
     */
    output wire [63:0]                  m_axis_tdata,
    output wire                         m_axis_tvalid,
    input  wire                         m_axis_tready,
    output wire                         m_axis_tlast,
    output wire                         m_axis_tuser,

    /*
     * From rc_regs: active set and control bits, sampled at an accepted start of frame
     */
    input  wire                         applied,
    input  wire [15:0]                  act_width,
    input  wire [15:0]                  act_height,
    input  wire [15:0]                  act_lb_delay,
    input  wire                         ctl_enable,
    input  wire                         ctl_bypass,
    input  wire                         ctl_gray,
    input  wire                         ctl_debug_line,
    input  wire [15:0]                  debug_row,
    input  wire                         apply_pending,

    /*
     * To rc_regs
     */
    output wire                         idle,
    output wire                         frame_done,
    output wire                         set_lb_overflow,
    output wire                         set_size_error,
    output wire                         busy,

    /*
     * Coordinate engine: start pulse and frame size; positions, one word per output pixel
     */
    output wire                         coord_start,
    output wire [15:0]                  coord_width,
    output wire [15:0]                  coord_height,
    input  wire                         pos_valid,
    output wire                         pos_ready,
    input  wire signed [`RC_POS_W-1:0]  pos_iu_l,
    input  wire signed [`RC_POS_W-1:0]  pos_iv_l,
    input  wire                         pos_ok_l,
    input  wire signed [`RC_POS_W-1:0]  pos_iu_r,
    input  wire signed [`RC_POS_W-1:0]  pos_iv_r,
    input  wire                         pos_ok_r
);

/*
 * Sizes
 */
localparam SZ = `RC_SIZE_W;                  // column and row counters
localparam PW = `RC_POS_W;                   // positions iu, iv: signed, 1/32 px
localparam FB = `RC_FRAC_BITS;               // fraction bits of a position
localparam IW = PW - FB;                     // integer part of a position, signed
localparam XW = IW + 2;                      // signed width of the edge and window compares
localparam LBW = COLOUR != 0 ? 24 : 8;       // line buffer word: RGB or gray
localparam SIDE_W = 64 - 2 * LBW;            // the rest of a beat (side buffer, for BYPASS)
localparam NS = (LB_ROWS + 2) / 2;           // slots per bank: ceil((LB_ROWS + 1) / 2)
localparam CW = (MAX_WIDTH + 1) / 2;         // words per slot: ceil(MAX_WIDTH / 2)
localparam DEPTH = NS * CW;                  // words per bank
localparam AW = $clog2(DEPTH);
localparam SW = $clog2(NS) + 1;              // slot numbers and slot differences
localparam CWB = $clog2(CW) < 1 ? 1 : $clog2(CW);  // column / 2
localparam CB = $clog2(MAX_WIDTH) < 1 ? 1 : $clog2(MAX_WIDTH);  // column in the side buffer
localparam NCH = COLOUR != 0 ? 4 : 1;        // channels interpolated: R, G, B, gray or gray
localparam FIFO_W = 64 + 3;                  // data, TLAST, TUSER, last beat of the frame
localparam CRW = $clog2(FIFO_DEPTH) + 1;     // credit counter

// pixel pipeline stages (clocks after the issue register, stage 0)
localparam RAM_LAT = 2;                      // rc_ram read latency
localparam INTERP_LAT = 6;                   // rc_interp latency
localparam ST_ADDR = 4;                      // bank read addresses
localparam ST_DATA = ST_ADDR + RAM_LAT;      // bank data
localparam ST_TAP = ST_DATA + 1;             // the four taps, masked
localparam GL = COLOUR != 0 ? 2 : 0;         // rc_gray
localparam ST_INTERP = ST_TAP + GL;          // rc_interp inputs
localparam ST_OUT = ST_INTERP + INTERP_LAT;  // rc_interp outputs: the output word is built
localparam ST_SIDE = ST_OUT - RAM_LAT;       // side buffer read address

localparam [SZ-1:0] ONE = 1;
localparam [31:0] NS_32 = NS;
localparam [SW:0] NS_V = NS_32[SW:0];           // NS
localparam [SW-1:0] NS_LAST = NS_32[SW-1:0] - 1'b1;  // NS - 1

// slot -> slot * CW, a small table (no multiplier): entry s of SLOT_BASES, SLOT_STRIDE bits
// from bit s * SLOT_STRIDE (a power of two: the index is a shift), is s * CW for s < NS and 0
// above. A slot number reads its entry, which a simulator looks up in one step where a chain
// of NS compares would cost it NS steps.
// verilator lint_off UNUSEDSIGNAL
localparam SLOT_STRIDE = 1 << $clog2(AW);
localparam NSLOT = 1 << SW;                  // slot numbers SW bits can hold
function [NSLOT*SLOT_STRIDE-1:0] slot_bases;
    input integer unused;
    integer k;
    reg [31:0] v;
    begin
        slot_bases = {NSLOT*SLOT_STRIDE{1'b0}};
        for (k = 1; k < NS; k = k + 1) begin
            v = k * CW;
            slot_bases[k*SLOT_STRIDE +: AW] = v[AW-1:0];
        end
    end
endfunction
localparam [NSLOT*SLOT_STRIDE-1:0] SLOT_BASES = slot_bases(0);

function [AW-1:0] slot_base;
    input [SW-1:0] s;
    begin
        slot_base = SLOT_BASES[{s, {$clog2(AW){1'b0}}} +: AW];
    end
endfunction
// verilator lint_on UNUSEDSIGNAL

/*
 * Input register slice
 */
wire [63:0] b_data;
wire        b_user;
wire        b_last;
wire        b_valid;
reg         b_take;

rc_skid #(
    .WIDTH(66)
)
skid_inst (
    .clk(clk),
    .rst(rst),
    .s_data({s_axis_tuser, s_axis_tlast, s_axis_tdata}),
    .s_valid(s_axis_tvalid),
    .s_ready(s_axis_tready),
    .m_data({b_user, b_last, b_data}),
    .m_valid(b_valid),
    .m_ready(b_take)
);

/*
 * Frame state, sampled at an accepted start of frame
 */
reg [SZ-1:0] f_width_reg = {SZ{1'b0}};
reg [SZ-1:0] f_height_reg = {SZ{1'b0}};
reg [SZ-1:0] f_e0_reg = {SZ{1'b0}};          // e(0)
reg          f_bypass_reg = 1'b0;
reg          f_gray_reg = 1'b0;
reg          f_debug_reg = 1'b0;
reg [15:0]   f_debug_row_reg = 16'd0;

reg [SZ-1:0] f_w1_reg = {SZ{1'b0}};         // WIDTH - 1
reg [SZ-1:0] f_h1_reg = {SZ{1'b0}};         // HEIGHT - 1

wire [SZ-1:0] f_w1 = f_w1_reg;
wire [SZ-1:0] f_h1 = f_h1_reg;

/*
 * Input checking and line buffer writes
 */
localparam IN_SEEK = 1'b0, IN_ROW = 1'b1;

reg          in_state_reg = IN_SEEK;
reg          in_tail_reg = 1'b0;             // the frame's HEIGHT lines are in: more is "frame long"
reg          in_ended_reg = 1'b0;            // the frame's input is over (complete or in error)
reg [SZ-1:0] in_row_reg = {SZ{1'b0}};        // complete rows of the frame (= the row being received)
reg [SZ-1:0] in_col_reg = {SZ{1'b0}};
reg [SW-1:0] wslot_reg = {SW{1'b0}};         // slot of the row being received
reg [AW-1:0] wbase_reg = {AW{1'b0}};         // its first address
reg [SW-1:0] hr0_reg = {SW{1'b0}};           // slot of row e(0)
reg [SZ-1:0] e_rd_reg = {SZ{1'b0}};          // e(y) of the oldest output row still reading
reg [SZ:0]   e_rd1_reg = {SZ+1{1'b0}};       // e_rd + 1: the last input row that may be received
reg          size_error_reg = 1'b0;

// output side state the input side looks at
localparam O_IDLE = 2'd0, O_WAIT0 = 2'd1, O_RUN = 2'd2, O_FLUSH = 2'd3;
reg [1:0] o_state_reg = O_IDLE;

reg in_start;      // accept the TUSER beat's frame (the beat itself is taken next clock)
reg in_write;      // a beat of the current row is taken and written
reg in_row_done;   // ... and it completes the row
reg in_error;      // an input error
reg in_tail_error; // a beat after the HEIGHT-th line

wire can_start = ctl_enable && !apply_pending && o_state_reg == O_IDLE;
wire at_first = in_row_reg == {SZ{1'b0}} && in_col_reg == {SZ{1'b0}};
wire row_allowed = {1'b0, in_row_reg} <= e_rd1_reg;
wire col_last = in_col_reg == f_w1;

always @* begin
    b_take = 1'b0;
    in_start = 1'b0;
    in_write = 1'b0;
    in_row_done = 1'b0;
    in_error = 1'b0;
    in_tail_error = 1'b0;

    if (b_valid) begin
        if (in_state_reg == IN_SEEK) begin
            if (!b_user) begin
                // discarded; after a complete frame it is the frame-long error
                b_take = 1'b1;
                in_tail_error = in_tail_reg;
            end else if (can_start) begin
                in_start = 1'b1;
            end
        end else begin
            if (b_user && !at_first) begin
                // start of frame early: this frame ends, the beat starts the next one
                in_error = 1'b1;
            end else if (row_allowed) begin
                b_take = 1'b1;
                in_write = 1'b1;
                if (col_last) begin
                    if (b_last) begin
                        in_row_done = 1'b1;
                    end else begin
                        in_error = 1'b1;  // line long
                    end
                end else if (b_last) begin
                    in_error = 1'b1;      // line short
                end
            end
        end
    end
end

// e(0) of a frame starting now
wire        start_bypass = ctl_bypass || !applied;
wire [15:0] start_h1 = act_height - 16'd1;
wire [15:0] start_e0 = start_bypass ? 16'd0 : (act_lb_delay < start_h1 ? act_lb_delay : start_h1);

always @(posedge clk) begin
    size_error_reg <= in_error || in_tail_error;

    if (in_tail_error) begin
        in_tail_reg <= 1'b0;
    end

    if (in_start) begin
        in_state_reg <= IN_ROW;
        in_tail_reg <= 1'b0;
        in_ended_reg <= 1'b0;
        in_row_reg <= {SZ{1'b0}};
        in_col_reg <= {SZ{1'b0}};
        wslot_reg <= {SW{1'b0}};
        wbase_reg <= {AW{1'b0}};
        f_width_reg <= act_width[SZ-1:0];
        f_height_reg <= act_height[SZ-1:0];
        f_w1_reg <= act_width[SZ-1:0] - ONE;
        f_h1_reg <= start_h1[SZ-1:0];
        f_e0_reg <= start_e0[SZ-1:0];
        f_bypass_reg <= start_bypass;
        f_gray_reg <= ctl_gray || COLOUR == 0;
        f_debug_reg <= ctl_debug_line;
        f_debug_row_reg <= debug_row;
    end

    if (in_write) begin
        in_col_reg <= (col_last || b_last) ? {SZ{1'b0}} : in_col_reg + ONE;
    end

    if (in_row_done) begin
        in_row_reg <= in_row_reg + ONE;
        if (in_row_reg[0]) begin
            // the next row starts the next pair of rows: next slot
            if (wslot_reg == NS_LAST) begin
                wslot_reg <= {SW{1'b0}};
                wbase_reg <= {AW{1'b0}};
            end else begin
                wslot_reg <= wslot_reg + 1'b1;
                wbase_reg <= wbase_reg + CW[AW-1:0];
            end
        end
        if (in_row_reg == f_e0_reg) begin
            hr0_reg <= wslot_reg;
        end
        if (in_row_reg == f_h1) begin
            in_ended_reg <= 1'b1;
            in_tail_reg <= 1'b1;
            in_state_reg <= IN_SEEK;
        end
    end

    if (in_error) begin
        in_ended_reg <= 1'b1;
        in_state_reg <= IN_SEEK;
    end

    if (rst) begin
        in_state_reg <= IN_SEEK;
        in_tail_reg <= 1'b0;
        in_ended_reg <= 1'b0;
        size_error_reg <= 1'b0;
    end
end

// line buffer and side buffer writes, one clock after the beat is taken
reg              w_en_reg = 1'b0;
reg              w_rp_reg = 1'b0;
reg              w_cp_reg = 1'b0;
reg [AW-1:0]     w_addr_reg = {AW{1'b0}};
reg [LBW-1:0]    w_data_l_reg = {LBW{1'b0}};
reg [LBW-1:0]    w_data_r_reg = {LBW{1'b0}};
reg [CB:0]       w_side_addr_reg = {CB+1{1'b0}};
reg [SIDE_W-1:0] w_side_data_reg = {SIDE_W{1'b0}};

// a beat's bits for the line buffers (per camera) and the side buffer
wire [LBW-1:0]    line_data_l;
wire [LBW-1:0]    line_data_r;
wire [SIDE_W-1:0] side_data_in;

generate
    if (COLOUR != 0) begin : g_split_colour
        assign line_data_l = b_data[23:0];
        assign line_data_r = b_data[55:32];
        assign side_data_in = {b_data[63:56], b_data[31:24]};
    end else begin : g_split_gray
        assign line_data_l = b_data[31:24];
        assign line_data_r = b_data[63:56];
        assign side_data_in = {b_data[55:32], b_data[23:0]};
    end
endgenerate

wire [AW-1:0] w_col_half = {{AW-CWB{1'b0}}, in_col_reg[CWB:1]};

always @(posedge clk) begin
    w_en_reg <= in_write;
    w_rp_reg <= in_row_reg[0];
    w_cp_reg <= in_col_reg[0];
    w_addr_reg <= wbase_reg + w_col_half;
    w_side_addr_reg <= {in_row_reg[0], in_col_reg[CB-1:0]};
    w_data_l_reg <= line_data_l;
    w_data_r_reg <= line_data_r;
    w_side_data_reg <= side_data_in;

    if (rst) begin
        w_en_reg <= 1'b0;
    end
end

/*
 * Output sequencing and pixel issue
 */
reg [SZ-1:0]  x_is_reg = {SZ{1'b0}};
reg [SZ-1:0]  y_is_reg = {SZ{1'b0}};
reg [SZ-1:0]  e_is_reg = {SZ{1'b0}};         // e(y) of the row being issued
reg [SW-1:0]  hr_is_reg = {SW{1'b0}};        // slot of row e(y)
reg           phase_reg = 1'b0;              // 1: the right camera's item is issued now
reg [CRW-1:0] credit_used_reg = {CRW{1'b0}}; // pixels issued and not yet sent
reg           coord_start_reg = 1'b0;
reg           frame_done_reg = 1'b0;

// the right camera's item and the pixel's flags, held for the second clock
reg signed [PW-1:0] h_iu_reg = {PW{1'b0}};
reg signed [PW-1:0] h_iv_reg = {PW{1'b0}};
reg                 h_ok_reg = 1'b0;

wire x_last = x_is_reg == f_w1;
// row_complete = in_row_reg > e_is_reg (input row e(y) is in), kept in a register: it is computed
// from the two counters' next values, so that the compare is not on the path into issue and the
// coordinate FIFO's pop (the longest path of the core otherwise).
wire [SZ-1:0] in_row_next = in_row_done ? in_row_reg + ONE : in_start ? {SZ{1'b0}} : in_row_reg;
wire          e_is_go = o_state_reg == O_WAIT0 && in_row_reg > f_e0_reg;
wire          e_is_inc = o_state_reg == O_RUN && phase_reg && x_last && e_is_reg != f_h1;
wire [SZ-1:0] e_is_next = e_is_go ? f_e0_reg : e_is_inc ? e_is_reg + ONE : e_is_reg;
reg           row_complete_reg = 1'b0;
always @(posedge clk) row_complete_reg <= in_row_next > e_is_next;
wire row_complete = row_complete_reg;
wire y_last = y_is_reg == f_h1;
wire issue = o_state_reg == O_RUN && !phase_reg && credit_used_reg < FIFO_DEPTH
    && (row_complete || in_ended_reg) && (f_bypass_reg || pos_valid);

wire fifo_pop;
wire fifo_pop_last;

assign pos_ready = issue && !f_bypass_reg;

// BYPASS: the position of pixel (x, y) is (32 x, 32 y)
wire signed [PW-1:0] bypass_iu = {{PW-FB-SZ{1'b0}}, x_is_reg, {FB{1'b0}}};
wire signed [PW-1:0] bypass_iv = {{PW-FB-SZ{1'b0}}, y_is_reg, {FB{1'b0}}};

// stage 0: the item register
reg                 p0_v_reg = 1'b0;
reg                 p0_cam_reg = 1'b0;
reg signed [PW-1:0] p0_iu_reg = {PW{1'b0}};
reg signed [PW-1:0] p0_iv_reg = {PW{1'b0}};
reg                 p0_ok_reg = 1'b0;
reg                 p0_zero_reg = 1'b0;      // a row the input never completed: 0
reg                 p0_debug_reg = 1'b0;
reg                 p0_first_reg = 1'b0;
reg                 p0_last_reg = 1'b0;
reg                 p0_flast_reg = 1'b0;
reg [SZ-1:0]        p0_e_reg = {SZ{1'b0}};
// e(y) - y0 of the item (stage 1's window compares), computed as the item is loaded:
// the subtract is then off the path through the compares into the tap flags
reg signed [XW-1:0] p0_dd_reg = {XW{1'b0}};
wire signed [PW-1:0] iv_l_sel = f_bypass_reg ? bypass_iv : pos_iv_l;
wire signed [XW-1:0] dd_l = {{XW-SZ{1'b0}}, e_is_reg} - {{XW-IW{iv_l_sel[PW-1]}}, iv_l_sel[PW-1:FB]};
wire signed [XW-1:0] dd_r = {{XW-SZ{1'b0}}, p0_e_reg} - {{XW-IW{h_iv_reg[PW-1]}}, h_iv_reg[PW-1:FB]};
reg [SW-1:0]        p0_hr_reg = {SW{1'b0}};

always @(posedge clk) begin
    coord_start_reg <= 1'b0;
    frame_done_reg <= fifo_pop_last;
    credit_used_reg <= credit_used_reg + {{CRW-1{1'b0}}, issue} - {{CRW-1{1'b0}}, fifo_pop};

    case (o_state_reg)
        O_IDLE: begin
            if (in_start) begin
                o_state_reg <= O_WAIT0;
            end
        end
        O_WAIT0: begin
            if (in_row_reg > f_e0_reg) begin
                // row e(0) is in: output row 0 may start
                o_state_reg <= O_RUN;
                coord_start_reg <= !f_bypass_reg;
                x_is_reg <= {SZ{1'b0}};
                y_is_reg <= {SZ{1'b0}};
                e_is_reg <= f_e0_reg;
                hr_is_reg <= hr0_reg;
                phase_reg <= 1'b0;
            end else if (in_ended_reg) begin
                // input ended before row e(0): the frame is dropped
                o_state_reg <= O_IDLE;
            end
        end
        O_RUN: begin
            if (issue) begin
                phase_reg <= 1'b1;
            end
            if (phase_reg) begin
                phase_reg <= 1'b0;
                if (x_last) begin
                    x_is_reg <= {SZ{1'b0}};
                    y_is_reg <= y_is_reg + ONE;
                    if (e_is_reg != f_h1) begin
                        e_is_reg <= e_is_reg + ONE;
                        if (e_is_reg[0]) begin
                            hr_is_reg <= hr_is_reg == NS_LAST ? {SW{1'b0}} : hr_is_reg + 1'b1;
                        end
                    end
                    if (y_last) begin
                        o_state_reg <= O_FLUSH;
                    end
                end else begin
                    x_is_reg <= x_is_reg + ONE;
                end
            end
        end
        default: begin  // O_FLUSH: the last pixel is issued, wait for its beat to leave
            if (fifo_pop_last) begin
                o_state_reg <= O_IDLE;
            end
        end
    endcase

    if (rst) begin
        o_state_reg <= O_IDLE;
        phase_reg <= 1'b0;
        credit_used_reg <= {CRW{1'b0}};
        coord_start_reg <= 1'b0;
        frame_done_reg <= 1'b0;
    end
end

always @(posedge clk) begin
    p0_v_reg <= issue || phase_reg;
    p0_cam_reg <= phase_reg;
    if (issue) begin
        p0_iu_reg <= f_bypass_reg ? bypass_iu : pos_iu_l;
        p0_iv_reg <= iv_l_sel;
        p0_dd_reg <= dd_l;
        p0_ok_reg <= f_bypass_reg || pos_ok_l;
        h_iu_reg <= f_bypass_reg ? bypass_iu : pos_iu_r;
        h_iv_reg <= f_bypass_reg ? bypass_iv : pos_iv_r;
        h_ok_reg <= f_bypass_reg || pos_ok_r;
        p0_zero_reg <= !row_complete;
        p0_debug_reg <= f_debug_reg && {{16-SZ{1'b0}}, y_is_reg} == f_debug_row_reg;
        p0_first_reg <= x_is_reg == {SZ{1'b0}} && y_is_reg == {SZ{1'b0}};
        p0_last_reg <= x_last;
        p0_flast_reg <= x_last && y_last;
        p0_e_reg <= e_is_reg;
        p0_hr_reg <= hr_is_reg;
    end else if (phase_reg) begin
        p0_iu_reg <= h_iu_reg;
        p0_iv_reg <= h_iv_reg;
        p0_dd_reg <= dd_r;
        p0_ok_reg <= h_ok_reg;
    end

    if (rst) begin
        p0_v_reg <= 1'b0;
    end
end

/*
 * Stage 1: taps' rows and columns, edges, window, slot offsets
 */
wire signed [IW-1:0] x0 = p0_iu_reg[PW-1:FB];
wire signed [IW-1:0] y0 = p0_iv_reg[PW-1:FB];
wire signed [XW-1:0] x0s = {{XW-IW{x0[IW-1]}}, x0};
wire signed [XW-1:0] y0s = {{XW-IW{y0[IW-1]}}, y0};
wire signed [XW-1:0] width_s = {{XW-SZ{1'b0}}, f_width_reg};
wire signed [XW-1:0] height_s = {{XW-SZ{1'b0}}, f_height_reg};
wire signed [XW-1:0] dd = p0_dd_reg;         // e(y) - y0
localparam signed [XW-1:0] S_ONE = 1;
localparam signed [XW-1:0] S_MONE = -1;
localparam [31:0] LB_ROWS_V = LB_ROWS;
localparam signed [XW-1:0] S_LB = LB_ROWS_V[XW-1:0];

// column x0 + dx inside the image, row y0 + dy inside the image, and inside the window
wire col_in0 = !x0s[XW-1] && x0s < width_s;
wire col_in1 = x0s >= S_MONE && x0s < width_s - S_ONE;
wire row_in0 = !y0s[XW-1] && y0s < height_s;
wire row_in1 = y0s >= S_MONE && y0s < height_s - S_ONE;
wire win0 = !dd[XW-1] && dd < S_LB;
wire win1 = dd >= S_ONE && dd <= S_LB;

wire p0_use = p0_ok_reg && !p0_zero_reg;
wire [3:0] tap_ok = {
    p0_use && col_in1 && row_in1 && win1,
    p0_use && col_in0 && row_in1 && win1,
    p0_use && col_in1 && row_in0 && win0,
    p0_use && col_in0 && row_in0 && win0
};
wire overflow = p0_use && !f_bypass_reg
    && (((col_in0 || col_in1) && row_in0 && !win0) || ((col_in0 || col_in1) && row_in1 && !win1));

// bank row parity rp holds tap row t = y0 (y0[0] == rp) or y0 + 1; its pair number t / 2,
// counted back from e(y) / 2 (valid for rows inside the window: 0 .. NS - 1)
wire [SW-1:0] e_half = p0_e_reg[SW:1];
wire [SW-1:0] y_half = y0[SW:1];
wire [SW-1:0] back0 = e_half - (y_half + {{SW-1{1'b0}}, y0[0]});
wire [SW-1:0] back1 = e_half - y_half;
// bank column parity cp holds tap column x0 (x0[0] == cp) or x0 + 1: its word in the slot
wire [CWB-1:0] x_half = x0[CWB:1];
wire [CWB-1:0] col_half0 = x_half + {{CWB-1{1'b0}}, x0[0]};
wire [CWB-1:0] col_half1 = x_half;

reg                 p1_overflow_reg = 1'b0;
reg [FB-1:0]        p1_du_reg = {FB{1'b0}};
reg [FB-1:0]        p1_dv_reg = {FB{1'b0}};
reg                 p1_xodd_reg = 1'b0;
reg                 p1_yodd_reg = 1'b0;
reg [3:0]           p1_tap_ok_reg = 4'd0;
reg [SW-1:0]        p1_back0_reg = {SW{1'b0}};
reg [SW-1:0]        p1_back1_reg = {SW{1'b0}};
reg [SW-1:0]        p1_hr_reg = {SW{1'b0}};
reg [CWB-1:0]       p1_col_half0_reg = {CWB{1'b0}};
reg [CWB-1:0]       p1_col_half1_reg = {CWB{1'b0}};
reg [CB:0]          p1_side_addr_reg = {CB+1{1'b0}};

always @(posedge clk) begin
    p1_overflow_reg <= p0_v_reg && overflow;
    p1_du_reg <= p0_iu_reg[FB-1:0];
    p1_dv_reg <= p0_iv_reg[FB-1:0];
    p1_xodd_reg <= x0[0];
    p1_yodd_reg <= y0[0];
    p1_tap_ok_reg <= tap_ok;
    p1_back0_reg <= back0;
    p1_back1_reg <= back1;
    p1_hr_reg <= p0_hr_reg;
    p1_col_half0_reg <= col_half0;
    p1_col_half1_reg <= col_half1;
    p1_side_addr_reg <= {y0[0], x0[CB-1:0]};

    if (rst) begin
        p1_overflow_reg <= 1'b0;
    end
end

assign set_lb_overflow = p1_overflow_reg;

/*
 * Stage 2: slots, (slot of e(y) - back) mod NS
 */
wire [SW:0] slot0_d = {1'b0, p1_hr_reg} - {1'b0, p1_back0_reg};
wire [SW:0] slot1_d = {1'b0, p1_hr_reg} - {1'b0, p1_back1_reg};

reg [SW-1:0]  p2_slot0_reg = {SW{1'b0}};
reg [SW-1:0]  p2_slot1_reg = {SW{1'b0}};
reg [CWB-1:0] p2_col_half0_reg = {CWB{1'b0}};
reg [CWB-1:0] p2_col_half1_reg = {CWB{1'b0}};

always @(posedge clk) begin
    p2_slot0_reg <= slot0_d[SW] ? slot0_d[SW-1:0] + NS_V[SW-1:0] : slot0_d[SW-1:0];
    p2_slot1_reg <= slot1_d[SW] ? slot1_d[SW-1:0] + NS_V[SW-1:0] : slot1_d[SW-1:0];
    p2_col_half0_reg <= p1_col_half0_reg;
    p2_col_half1_reg <= p1_col_half1_reg;
end

/*
 * Stage 3: slot bases; stage 4: the four bank addresses (bank b = {row parity, column parity})
 */
reg [AW-1:0]   p3_base0_reg = {AW{1'b0}};
reg [AW-1:0]   p3_base1_reg = {AW{1'b0}};
reg [CWB-1:0]  p3_col_half0_reg = {CWB{1'b0}};
reg [CWB-1:0]  p3_col_half1_reg = {CWB{1'b0}};
reg [4*AW-1:0] p4_addr_reg = {4*AW{1'b0}};

wire [AW-1:0] col_half0_a = {{AW-CWB{1'b0}}, p3_col_half0_reg};
wire [AW-1:0] col_half1_a = {{AW-CWB{1'b0}}, p3_col_half1_reg};

always @(posedge clk) begin
    p3_base0_reg <= slot_base(p2_slot0_reg);
    p3_base1_reg <= slot_base(p2_slot1_reg);
    p3_col_half0_reg <= p2_col_half0_reg;
    p3_col_half1_reg <= p2_col_half1_reg;

    p4_addr_reg <= {p3_base1_reg + col_half1_a, p3_base1_reg + col_half0_a,
                    p3_base0_reg + col_half1_a, p3_base0_reg + col_half0_a};
end

// item control carried down the pipeline: {v, cam, zero, debug, first, last, flast}
localparam CTL_W = 7;
wire [CTL_W-1:0] ctl_p0 = {p0_v_reg, p0_cam_reg, p0_zero_reg, p0_debug_reg,
                           p0_first_reg, p0_last_reg, p0_flast_reg};
wire [CTL_W-1:0] ctl_addr;
wire [CTL_W-1:0] ctl_side;
wire [CTL_W-1:0] ctl_out;

rc_delay #(.WIDTH(CTL_W), .LATENCY(ST_ADDR), .RESET(1))
ctl_addr_inst (.clk(clk), .rst(rst), .in(ctl_p0), .out(ctl_addr));
rc_delay #(.WIDTH(CTL_W), .LATENCY(ST_SIDE - ST_ADDR), .RESET(1))
ctl_side_inst (.clk(clk), .rst(rst), .in(ctl_addr), .out(ctl_side));
rc_delay #(.WIDTH(CTL_W), .LATENCY(ST_OUT - ST_SIDE), .RESET(1))
ctl_out_inst (.clk(clk), .rst(rst), .in(ctl_side), .out(ctl_out));

wire addr_v = ctl_addr[6];
wire addr_cam = ctl_addr[5];

/*
 * Line buffers: one per camera, read by that camera's item
 */
wire [4*LBW-1:0] rd_l;
wire [4*LBW-1:0] rd_r;

rc_linebuf #(.WIDTH(LBW), .DEPTH(DEPTH), .AW(AW))
lb_l_inst (
    .clk(clk),
    .we(w_en_reg), .wrow_par(w_rp_reg), .wcol_par(w_cp_reg), .waddr(w_addr_reg), .wdata(w_data_l_reg),
    .re(addr_v && !addr_cam), .raddr(p4_addr_reg), .rdata(rd_l)
);

rc_linebuf #(.WIDTH(LBW), .DEPTH(DEPTH), .AW(AW))
lb_r_inst (
    .clk(clk),
    .we(w_en_reg), .wrow_par(w_rp_reg), .wcol_par(w_cp_reg), .waddr(w_addr_reg), .wdata(w_data_r_reg),
    .re(addr_v && addr_cam), .raddr(p4_addr_reg), .rdata(rd_r)
);

// the fields the tap stage needs, from stage 1 (and the address stage) to the bank data
wire [5:0] sel_tap;  // {xodd, yodd, tap_ok}
wire       tap_cam;

rc_delay #(.WIDTH(6), .LATENCY(ST_DATA - 1), .RESET(0))
sel_inst (.clk(clk), .rst(rst), .in({p1_xodd_reg, p1_yodd_reg, p1_tap_ok_reg}), .out(sel_tap));
rc_delay #(.WIDTH(1), .LATENCY(RAM_LAT), .RESET(0))
tap_cam_inst (.clk(clk), .rst(rst), .in(addr_cam), .out(tap_cam));

/*
 * Stage ST_TAP: the four taps G0..G3 in tap order (bank {dy ^ yodd, dx ^ xodd}), 0 where not read
 */
wire tap_xodd = sel_tap[5];
wire tap_yodd = sel_tap[4];
wire [3:0] tap_use = sel_tap[3:0];
wire [4*LBW-1:0] rd_cam = tap_cam ? rd_r : rd_l;
reg  [4*LBW-1:0] tap_reg = {4*LBW{1'b0}};

// tap t = {dy, dx} lies in bank {dy ^ yodd, dx ^ xodd}
// (a case on constant slices: a variable part-select of the bus simulates slowly)
function [LBW-1:0] tap_word;
    input [4*LBW-1:0] banks;
    input [1:0] t;
    input xodd;
    input yodd;
    reg [1:0] b;
    begin
        b = {t[1] ^ yodd, t[0] ^ xodd};
        case (b)
            2'd0: tap_word = banks[0*LBW +: LBW];
            2'd1: tap_word = banks[1*LBW +: LBW];
            2'd2: tap_word = banks[2*LBW +: LBW];
            default: tap_word = banks[3*LBW +: LBW];
        endcase
    end
endfunction

always @(posedge clk) begin
    tap_reg[0*LBW +: LBW] <= tap_use[0] ? tap_word(rd_cam, 2'd0, tap_xodd, tap_yodd) : {LBW{1'b0}};
    tap_reg[1*LBW +: LBW] <= tap_use[1] ? tap_word(rd_cam, 2'd1, tap_xodd, tap_yodd) : {LBW{1'b0}};
    tap_reg[2*LBW +: LBW] <= tap_use[2] ? tap_word(rd_cam, 2'd2, tap_xodd, tap_yodd) : {LBW{1'b0}};
    tap_reg[3*LBW +: LBW] <= tap_use[3] ? tap_word(rd_cam, 2'd3, tap_xodd, tap_yodd) : {LBW{1'b0}};
end

/*
 * Per-tap gray (COLOUR 1): taps become {Y, B, G, R}
 */
localparam TW = COLOUR != 0 ? 32 : 8;
wire [4*TW-1:0] taps;

genvar g;
generate
    if (COLOUR != 0) begin : g_gray
        for (g = 0; g < 4; g = g + 1) begin : g_tap
            rc_gray gray_inst (.clk(clk), .rgb(tap_reg[g*LBW +: LBW]), .rgby(taps[g*TW +: TW]));
        end
    end else begin : g_no_gray
        assign taps = tap_reg;
    end
endgenerate

// fractions, from stage 1 to ST_INTERP
wire [2*FB-1:0] frac_interp;

rc_delay #(.WIDTH(2*FB), .LATENCY(ST_INTERP - 1), .RESET(0))
frac_inst (.clk(clk), .rst(rst), .in({p1_dv_reg, p1_du_reg}), .out(frac_interp));

/*
 * Interpolation, one rc_interp per channel
 */
wire [8*NCH-1:0] ch_out;

generate
    for (g = 0; g < NCH; g = g + 1) begin : g_ch
        rc_interp interp_inst (
            .clk(clk),
            .g0(taps[0*TW + 8*g +: 8]),
            .g1(taps[1*TW + 8*g +: 8]),
            .g2(taps[2*TW + 8*g +: 8]),
            .g3(taps[3*TW + 8*g +: 8]),
            .du(frac_interp[FB-1:0]),
            .dv(frac_interp[2*FB-1:FB]),
            .out(ch_out[8*g +: 8])
        );
    end
endgenerate

/*
 * Side buffer (BYPASS): the beat's bits the line buffer does not hold, two rows
 */
wire [CB:0] side_addr;
wire [SIDE_W-1:0] side_data;

rc_delay #(.WIDTH(CB+1), .LATENCY(ST_SIDE - 1), .RESET(0))
side_addr_inst (.clk(clk), .rst(rst), .in(p1_side_addr_reg), .out(side_addr));

rc_ram #(.WIDTH(SIDE_W), .DEPTH(2 << CB), .AW(CB+1))
side_inst (
    .clk(clk),
    .we(w_en_reg), .waddr(w_side_addr_reg), .wdata(w_side_data_reg),
    .re(ctl_side[6] && !ctl_side[5]), .raddr(side_addr), .rdata(side_data)
);

/*
 * Stage ST_OUT: the output word of one camera; left held, written with right
 */
wire out_v = ctl_out[6];
wire out_cam = ctl_out[5];
wire out_zero = ctl_out[4];
wire out_debug = ctl_out[3];
wire out_first = ctl_out[2];
wire out_last = ctl_out[1];
wire out_flast = ctl_out[0];

wire [7:0] y_i = ch_out[8*(NCH-1) +: 8];
wire [SIDE_W/2-1:0] side_cam = out_zero ? {SIDE_W/2{1'b0}}
    : (out_cam ? side_data[SIDE_W/2 +: SIDE_W/2] : side_data[0 +: SIDE_W/2]);
wire [31:0] cam_word;

generate
    if (COLOUR != 0) begin : g_word_colour
        // {Y, B, G, R}: BYPASS keeps the stream's gray byte, GRAY puts Y everywhere
        assign cam_word = out_debug ? 32'hffffffff
            : f_bypass_reg ? {side_cam, ch_out[23:0]}
            : f_gray_reg ? {4{y_i}}
            : ch_out;
    end else begin : g_word_gray
        // BYPASS keeps the stream's R, G, B; else Y everywhere
        assign cam_word = out_debug ? 32'hffffffff
            : f_bypass_reg ? {y_i, side_cam}
            : {4{y_i}};
    end
endgenerate

reg [31:0] left_word_reg = 32'd0;

always @(posedge clk) begin
    if (out_v && !out_cam) begin
        left_word_reg <= cam_word;
    end
end

/*
 * Output FIFO
 */
wire [FIFO_W-1:0] fifo_out;

// The writer counts credits (never more words inside than the FIFO holds): s_ready and count unused.
// verilator lint_off PINCONNECTEMPTY
rc_fifo #(.WIDTH(FIFO_W), .DEPTH(FIFO_DEPTH), .SHOW_AHEAD(1), .OUTPUT_REG(1))
fifo_inst (
    .clk(clk),
    .rst(rst),
    .s_data({out_flast, out_first, out_last, cam_word, left_word_reg}),
    .s_valid(out_v && out_cam),
    .s_ready(),
    .m_data(fifo_out),
    .m_valid(m_axis_tvalid),
    .m_ready(m_axis_tready),
    .count()
);
// verilator lint_on PINCONNECTEMPTY

assign m_axis_tdata = fifo_out[63:0];
assign m_axis_tlast = fifo_out[64];
assign m_axis_tuser = fifo_out[65];
assign fifo_pop = m_axis_tvalid && m_axis_tready;
assign fifo_pop_last = fifo_pop && fifo_out[66];

/*
 * Reads done: e(y) of the oldest output row whose reads (taps and side buffer) are not complete
 */
always @(posedge clk) begin
    if (in_start) begin
        e_rd_reg <= start_e0[SZ-1:0];
        e_rd1_reg <= {1'b0, start_e0[SZ-1:0]} + 1'b1;
    end else if (ctl_side[6] && ctl_side[5] && ctl_side[1] && e_rd_reg != f_h1) begin
        e_rd_reg <= e_rd_reg + ONE;
        e_rd1_reg <= e_rd1_reg + 1'b1;
    end
end

/*
 * Status
 */
assign idle = in_state_reg == IN_SEEK && o_state_reg == O_IDLE;
assign busy = !idle;
assign frame_done = frame_done_reg;
assign set_size_error = size_error_reg;
assign coord_start = coord_start_reg;
assign coord_width = {{16-SZ{1'b0}}, f_width_reg};
assign coord_height = {{16-SZ{1'b0}}, f_height_reg};

// MAX_HEIGHT only bounds the row counters (RC_SIZE_W); the active set's sizes were checked on APPLY
// verilator lint_off UNUSEDSIGNAL
wire unused_ok = &{1'b0, act_width[15:SZ], act_height[15:SZ], start_e0[15:SZ], MAX_HEIGHT[0], f_gray_reg};
// verilator lint_on UNUSEDSIGNAL

endmodule

`resetall
