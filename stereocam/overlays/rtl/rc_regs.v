// Language: Verilog 2005

`include "prelude.vh"

`include "rectify_spec.vh"

/*
 * rc_regs: the rectify core's register block (RECTIFY_CORE.md, "Registers" and
 * "Behaviour"; offsets, fields and formats are RECTIFY_MAP's, through
 * rectify_spec.vh).
 *
 * AXI4-Lite slave, RC_ADDR_W-bit byte address (the 4 KiB window of RECTIFY_MAP),
 * 32-bit data, every AXI output straight
 * from a register. AW and W are taken independently, in either order, one of
 * each held at a time; the write is done on the clock edge after both are
 * held (and B is free), byte by byte as WSTRB says, and BVALID rises on that
 * same edge. A read address is held and decoded on the next clock edge into
 * RDATA, RVALID rising on that edge. Throughput: one write and one read per
 * two clocks, in parallel. Responses are always OKAY: an address outside the
 * map reads 0 and ignores writes, read-only registers and bits ignore writes.
 * For SWEEP_N = 2 * 2^clog2(2 * RC_NPARAMS) = 128 clocks after reset the
 * ports take nothing (AWREADY, WREADY, ARREADY low) while the read-back copy
 * of the parameter words (distributed RAM) is cleared.
 *
 * Shadow and active sets. WIDTH, HEIGHT, LB_DELAY and the 2 x RC_NPARAMS
 * signed 64-bit parameters (LO/HI words) are shadow registers that read back
 * what was written (parameters from the read-back copy, written with them).
 * Range check, two stages: stage 1 flags each group of CHK_GROUP bits above
 * a parameter's sign bit (bit RC_<NAME>_W - 1) that differs from it (a
 * sign-extension comparison), FX and FY below RC_FX_MIN / RC_FY_MIN, WIDTH
 * and HEIGHT outside 1 .. MAX_WIDTH / MAX_HEIGHT, LB_DELAY at or above
 * MAX_HEIGHT, and is loaded on the clock edge after a shadow write or a
 * reset (the only edges after which its inputs change, so it always holds
 * the flags of the shadow set as it was one edge before); stage 2 ORs the
 * flags into all_ok_reg every clock.
 * CONTROL.APPLY (self-clearing) latches or refuses the set on the first clock
 * edge where `idle` is 1 and no shadow register was written on the two edges
 * before (so all_ok_reg describes exactly the set being latched):
 * - accepted: the active set takes the shadow (each parameter kept in its
 *   RC_<NAME>_W bits and sign-extended on act_l/act_r), `applied` rises;
 * - refused: FLAGS.CONFIG_ERROR rises and the active set is kept;
 * either way APPLY (CONTROL.APPLY, STATUS.APPLY_PENDING, `apply_pending`)
 * falls on that edge.
 * Latency: APPLY written with `idle` at 1 latches on the next clock edge
 * (writes are at least two clocks apart, so the check pipeline has always
 * caught up by then): apply_pending is 1 for exactly one clock. Otherwise the
 * latch is on the first edge where `idle` is 1.
 * Writing APPLY = 0 does not cancel a pending APPLY; writing 1 again while one
 * is pending changes nothing (the latch takes the shadow as it is then).
 *
 * FLAGS are sticky: raised by set_lb_overflow, set_size_error and a refused
 * APPLY, cleared by writing 1; a raise and a clear on the same edge: the
 * raise wins. FRAME_COUNT counts frame_done (one per clock at most),
 * wrapping at 2^32. STATUS.BUSY is `busy` when the read is decoded.
 *
 * Frame and line boundaries: none seen here. The datapath samples the
 * control outputs when it accepts a start of frame, accepts none while
 * apply_pending is 1, and holds `idle` at 1 only while no frame is in flight,
 * so the active set never changes under a frame.
 *
 * Reset: synchronous, active high: every register to its RECTIFY_MAP reset
 * value, the active set to zero with act_width/act_height at the reset
 * WIDTH/HEIGHT, `applied` 0; the AXI ready outputs low in reset and during
 * the 128-clock clearing after it.
 */

module rc_regs #
(
    // Build parameters, read back through MAX_WIDTH, MAX_HEIGHT, LB_ROWS, CAPS.COLOUR
    parameter MAX_WIDTH = `RC_BUILD_COLOUR_MAX_WIDTH,
    parameter MAX_HEIGHT = `RC_BUILD_COLOUR_MAX_HEIGHT,
    parameter LB_ROWS = `RC_BUILD_COLOUR_LB_ROWS,
    parameter COLOUR = `RC_BUILD_COLOUR_COLOUR
)
(
    input  wire                      clk,
    input  wire                      rst,

    /*
     * AXI4-Lite slave, RC_ADDR_W-bit byte address, 32-bit data
     */
    input  wire [`RC_ADDR_W-1:0]     s_axil_awaddr,
    input  wire                      s_axil_awvalid,
    output wire                      s_axil_awready,
    input  wire [31:0]               s_axil_wdata,
    input  wire [3:0]                s_axil_wstrb,
    input  wire                      s_axil_wvalid,
    output wire                      s_axil_wready,
    output wire [1:0]                s_axil_bresp,
    output wire                      s_axil_bvalid,
    input  wire                      s_axil_bready,
    input  wire [`RC_ADDR_W-1:0]     s_axil_araddr,
    input  wire                      s_axil_arvalid,
    output wire                      s_axil_arready,
    output wire [31:0]               s_axil_rdata,
    output wire [1:0]                s_axil_rresp,
    output wire                      s_axil_rvalid,
    input  wire                      s_axil_rready,

    /*
     * From the datapath
     */
    input  wire                      idle,             // no frame in flight: an APPLY may latch now
    input  wire                      frame_done,       // pulse: FRAME_COUNT + 1
    input  wire                      set_lb_overflow,  // pulse: raise FLAGS.LB_OVERFLOW
    input  wire                      set_size_error,   // pulse: raise FLAGS.SIZE_ERROR
    input  wire                      busy,             // STATUS.BUSY

    /*
     * To the datapath (active set, changes only while idle)
     */
    output wire                      applied,          // a set was latched since reset
    output wire [`RC_NPARAMS*64-1:0] act_l,            // parameter i (RC_P_*) at [64*i +: 64]
    output wire [`RC_NPARAMS*64-1:0] act_r,
    output wire [15:0]               act_width,
    output wire [15:0]               act_height,
    output wire [15:0]               act_lb_delay,
    output wire                      ctl_enable,
    output wire                      ctl_bypass,
    output wire                      ctl_gray,
    output wire                      ctl_debug_line,
    output wire [15:0]               debug_row,
    output wire                      apply_pending     // no start of frame may be accepted while 1
);

/*
 * Constants, all from rectify_spec.vh
 */
localparam AW = `RC_ADDR_W;                 // byte address bits
localparam NP = `RC_NPARAMS;                // parameters per camera
localparam SET_W = 64 * NP;                 // one camera's flat parameter vector
localparam NW = 2 * NP;                     // 32-bit words per camera block
localparam BLK_LSB = $clog2(8 * NP);        // a block's words are addressed by addr[BLK_LSB-1:2]
localparam IDX_W = BLK_LSB - 2;
localparam NW_PAD = 1 << IDX_W;             // words addressable in a block (the rest read 0)
localparam [AW-1:0] BLOCK_L = `RC_BLOCK_L;
localparam [AW-1:0] BLOCK_R = `RC_BLOCK_R;

localparam [31:0] MAX_WIDTH_V = MAX_WIDTH;
localparam [31:0] MAX_HEIGHT_V = MAX_HEIGHT;
localparam [31:0] LB_ROWS_V = LB_ROWS;

// CONTROL: read/write bits (APPLY is kept in apply_reg)
localparam [31:0] CONTROL_RW = (32'd1 << `RC_CONTROL_ENABLE) | (32'd1 << `RC_CONTROL_BYPASS)
                             | (32'd1 << `RC_CONTROL_GRAY) | (32'd1 << `RC_CONTROL_DEBUG_LINE);
localparam [31:0] FLAGS_W1C = (32'd1 << `RC_FLAGS_LB_OVERFLOW) | (32'd1 << `RC_FLAGS_SIZE_ERROR)
                            | (32'd1 << `RC_FLAGS_CONFIG_ERROR);
// VALUE fields of WIDTH, HEIGHT, LB_DELAY, DEBUG_ROW
localparam [31:0] WIDTH_MASK = ((32'd1 << `RC_WIDTH_VALUE_W) - 1) << `RC_WIDTH_VALUE;
localparam [31:0] HEIGHT_MASK = ((32'd1 << `RC_HEIGHT_VALUE_W) - 1) << `RC_HEIGHT_VALUE;
localparam [31:0] LB_DELAY_MASK = ((32'd1 << `RC_LB_DELAY_VALUE_W) - 1) << `RC_LB_DELAY_VALUE;
localparam [31:0] DEBUG_ROW_MASK = ((32'd1 << `RC_DEBUG_ROW_VALUE_W) - 1) << `RC_DEBUG_ROW_VALUE;
localparam [31:0] WIDTH_RESET = `RC_WIDTH_RESET << `RC_WIDTH_VALUE;
localparam [31:0] HEIGHT_RESET = `RC_HEIGHT_RESET << `RC_HEIGHT_VALUE;

// Signed width of parameter i (RC_P_* order)
function integer param_width;
    input integer i;
    begin
        case (i)
            `RC_P_N00: param_width = `RC_N00_W;
            `RC_P_N01: param_width = `RC_N01_W;
            `RC_P_N02: param_width = `RC_N02_W;
            `RC_P_N10: param_width = `RC_N10_W;
            `RC_P_N11: param_width = `RC_N11_W;
            `RC_P_N12: param_width = `RC_N12_W;
            `RC_P_N20: param_width = `RC_N20_W;
            `RC_P_N21: param_width = `RC_N21_W;
            `RC_P_N22: param_width = `RC_N22_W;
            `RC_P_FX: param_width = `RC_FX_W;
            `RC_P_FY: param_width = `RC_FY_W;
            `RC_P_CX: param_width = `RC_CX_W;
            `RC_P_CY: param_width = `RC_CY_W;
            `RC_P_K1: param_width = `RC_K1_W;
            `RC_P_K2: param_width = `RC_K2_W;
            `RC_P_P1: param_width = `RC_P1_W;
            `RC_P_P2: param_width = `RC_P2_W;
            default: param_width = 64;
        endcase
    end
endfunction

// Lowest accepted value of parameter i, when it is above its format's own (else 0: none)
function [63:0] param_min;
    input integer i;
    begin
        case (i)
            `RC_P_FX: param_min = `RC_FX_MIN;
            `RC_P_FY: param_min = `RC_FY_MIN;
            default: param_min = 64'd0;
        endcase
    end
endfunction

// The range checks take the bits above a parameter's sign bit in groups of CHK_GROUP
localparam CHK_GROUP = 5;

// groups above parameter i's sign bit
function integer param_groups;
    input integer i;
    begin
        param_groups = (64 - param_width(i) + CHK_GROUP - 1) / CHK_GROUP;
    end
endfunction

// first flag of parameter n in a camera's flags: its groups, then its minimum flag
function integer flag_base;
    input integer n;
    integer i;
    begin
        flag_base = 0;
        for (i = 0; i < n; i = i + 1) begin
            flag_base = flag_base + param_groups(i) + 1;
        end
    end
endfunction

// v < m for a constant m, as plain logic (a comparator would become a carry chain with a
// LUT per bit; this folds to a few LUTs): from bit 0 up, lt = v[i] < m[i] or (equal and lt)
function lt_const;
    input [63:0] v;
    input [63:0] m;
    integer i;
    begin
        lt_const = 1'b0;
        for (i = 0; i < 64; i = i + 1) begin
            lt_const = m[i] ? !v[i] || lt_const : !v[i] && lt_const;
        end
    end
endfunction

// A register word after a write: the bytes WSTRB selects from wdata, the others kept
// (a multiplexer per byte, so that synthesis makes it a clock enable per byte)
function [31:0] merge;
    input [31:0] old;
    input [31:0] wdata;
    input [3:0] wstrb;
    integer b;
    begin
        for (b = 0; b < 4; b = b + 1) begin
            merge[8*b +: 8] = wstrb[b] ? wdata[8*b +: 8] : old[8*b +: 8];
        end
    end
endfunction

genvar c, k, p;

// The decode below takes a block's words from addr[BLK_LSB-1:2] and the block from the
// bits above: each block must start on a multiple of 2^BLK_LSB bytes.
generate
    // verilator lint_off GENUNNAMED
    if ((`RC_BLOCK_L % (1 << BLK_LSB)) != 0 || (`RC_BLOCK_R % (1 << BLK_LSB)) != 0)
        rc_regs_parameter_block_not_aligned_to_its_size block_not_aligned();
    // verilator lint_on GENUNNAMED
endgenerate

/*
 * Read-back copy of the parameter words: after reset it is cleared one word per clock
 * (SWEEP_N clocks), and the AXI ports take nothing until then
 */
localparam SWEEP_N = 2 * NW_PAD;            // {camera, word index}

reg [IDX_W:0] sweep_reg = {(IDX_W+1){1'b0}}, sweep_next;
reg           sweeping_reg = 1'b1, sweeping_next;

always @* begin
    sweep_next = sweep_reg + 1'b1;
    sweeping_next = sweeping_reg && sweep_reg != SWEEP_N - 1;
end

always @(posedge clk) begin
    sweep_reg <= sweep_next;
    sweeping_reg <= sweeping_next;

    if (rst) begin
        sweep_reg <= {(IDX_W+1){1'b0}};
        sweeping_reg <= 1'b1;
    end
end

/*
 * AXI4-Lite write channels: AW and W held independently, write done when both are held
 */
reg [AW-1:2] aw_addr_reg = {(AW-2){1'b0}};
reg        aw_full_reg = 1'b0, aw_full_next;
reg [31:0] w_data_reg = 32'd0;
reg [3:0]  w_strb_reg = 4'hf;
reg        w_full_reg = 1'b0, w_full_next;
reg        s_axil_awready_reg = 1'b0;
reg        s_axil_wready_reg = 1'b0;
reg        s_axil_bvalid_reg = 1'b0, s_axil_bvalid_next;

wire do_write = aw_full_reg && w_full_reg && (!s_axil_bvalid_reg || s_axil_bready);
wire [31:0] w_mask = {{8{w_strb_reg[3]}}, {8{w_strb_reg[2]}}, {8{w_strb_reg[1]}}, {8{w_strb_reg[0]}}};

assign s_axil_awready = s_axil_awready_reg;
assign s_axil_wready = s_axil_wready_reg;
assign s_axil_bresp = 2'b00;  // OKAY
assign s_axil_bvalid = s_axil_bvalid_reg;

always @* begin
    aw_full_next = aw_full_reg;
    w_full_next = w_full_reg;
    s_axil_bvalid_next = s_axil_bvalid_reg && !s_axil_bready;

    if (do_write) begin
        aw_full_next = 1'b0;
        w_full_next = 1'b0;
        s_axil_bvalid_next = 1'b1;
    end
    if (s_axil_awvalid && s_axil_awready_reg) begin
        aw_full_next = 1'b1;
    end
    if (s_axil_wvalid && s_axil_wready_reg) begin
        w_full_next = 1'b1;
    end
end

always @(posedge clk) begin
    aw_full_reg <= aw_full_next;
    w_full_reg <= w_full_next;
    s_axil_awready_reg <= !aw_full_next && !sweeping_next;
    s_axil_wready_reg <= !w_full_next && !sweeping_next;
    s_axil_bvalid_reg <= s_axil_bvalid_next;

    if (rst) begin
        aw_full_reg <= 1'b0;
        w_full_reg <= 1'b0;
        s_axil_awready_reg <= 1'b0;
        s_axil_wready_reg <= 1'b0;
        s_axil_bvalid_reg <= 1'b0;
    end
end

// held address and data; in reset the data becomes a full zero word, which the sweep writes
always @(posedge clk) begin
    if (s_axil_awvalid && s_axil_awready_reg) begin
        aw_addr_reg <= s_axil_awaddr[AW-1:2];
    end
    if (s_axil_wvalid && s_axil_wready_reg) begin
        w_data_reg <= s_axil_wdata;
        w_strb_reg <= s_axil_wstrb;
    end

    if (rst) begin
        w_data_reg <= 32'd0;
        w_strb_reg <= 4'hf;
    end
end

// write decode: the parameter blocks here; the control registers' strobes wr_<name> are
// generated from RECTIFY_MAP (rc_regs_decode.vh, included below with the read multiplexer)
wire [IDX_W-1:0] wr_idx = aw_addr_reg[BLK_LSB-1:2];
wire wr_in_block = wr_idx < NW;
wire wr_l = do_write && aw_addr_reg[AW-1:BLK_LSB] == BLOCK_L[AW-1:BLK_LSB] && wr_in_block;
wire wr_r = do_write && aw_addr_reg[AW-1:BLK_LSB] == BLOCK_R[AW-1:BLK_LSB] && wr_in_block;
wire wr_control, wr_flags, wr_width, wr_height, wr_lb_delay, wr_debug_row;  // driven by rc_regs_decode.vh
// a write to the shadow set (the check pipeline must see it before a latch)
wire wr_shadow = wr_l || wr_r || wr_width || wr_height || wr_lb_delay;

/*
 * Shadow parameters: per camera c and parameter p, one 64-bit register (LO word 2p of the
 * camera's block in the low half, HI word 2p+1 in the high half), which the checks and the
 * active set read as g_shadow[c].g_param[p].value_reg. Written only on a write to the block,
 * so a simulator passes over them on every other clock.
 */
generate
    for (c = 0; c < 2; c = c + 1) begin : g_shadow
        for (p = 0; p < NP; p = p + 1) begin : g_param
            reg [63:0] value_reg = 64'd0;
            wire lo_we = wr_idx == 2 * p;
            wire hi_we = wr_idx == 2 * p + 1;

            always @(posedge clk) begin
                if (rst) begin
                    value_reg <= 64'd0;
                end else if (c == 0 ? wr_l : wr_r) begin
                    if (lo_we) begin
                        value_reg[31:0] <= merge(value_reg[31:0], w_data_reg, w_strb_reg);
                    end
                    if (hi_we) begin
                        value_reg[63:32] <= merge(value_reg[63:32], w_data_reg, w_strb_reg);
                    end
                end
            end
        end
    end
endgenerate

// The read-back copy, in distributed RAM (the FFs above feed the checks and the active
// set in parallel; a 2 x NW-word read multiplexer over them would cost ~1000 LUTs): one
// RAM per byte lane, so that WSTRB is a plain write enable to each. Words NW .. NW_PAD-1
// of each block are only ever written by the sweep: they read 0.
wire [IDX_W:0] mirror_waddr = sweeping_reg ? sweep_reg : {wr_r, wr_idx};
wire           mirror_we = sweeping_reg || wr_l || wr_r;
wire [IDX_W:0] mirror_raddr;
wire [31:0]    rd_mirror;

generate
    for (k = 0; k < 4; k = k + 1) begin : g_mirror
        (* ram_style = "distributed" *)
        reg [7:0] ram [0:SWEEP_N-1];

        always @(posedge clk) begin
            if (mirror_we && w_strb_reg[k]) begin
                ram[mirror_waddr] <= w_data_reg[8*k +: 8];
            end
        end

        assign rd_mirror[8*k +: 8] = ram[mirror_raddr];
    end
endgenerate

/*
 * Control and shadow frame registers
 */
reg [31:0] control_reg = 32'd0, control_next;
reg        apply_reg = 1'b0, apply_next;
reg [31:0] flags_reg = 32'd0, flags_next;
reg [31:0] frame_count_reg = 32'd0, frame_count_next;
reg [31:0] width_reg = WIDTH_RESET, width_next;
reg [31:0] height_reg = HEIGHT_RESET, height_next;
reg [31:0] lb_delay_reg = 32'd0, lb_delay_next;
reg [31:0] debug_row_reg = 32'd0, debug_row_next;

wire [15:0] width_value = width_reg[`RC_WIDTH_VALUE +: `RC_WIDTH_VALUE_W];
wire [15:0] height_value = height_reg[`RC_HEIGHT_VALUE +: `RC_HEIGHT_VALUE_W];
wire [15:0] lb_delay_value = lb_delay_reg[`RC_LB_DELAY_VALUE +: `RC_LB_DELAY_VALUE_W];

/*
 * Range checks, stage 1: per parameter, each group of up to CHK_GROUP bits above the sign
 * bit is flagged when one differs from the sign bit (a sign-extension comparison, one LUT6
 * a group), FX and FY when below their minimum; WIDTH, HEIGHT and LB_DELAY when out of
 * range. bad_reg loads them on the edge after a shadow write or a reset (wr_shadow_reg[0]:
 * reset sets it), i.e. whenever they may have changed; holding them otherwise changes no
 * value, and a simulator then skips the checks on every other clock. Stage 2 ORs the flags
 * into all_ok_reg.
 */
localparam NFLAG_CAM = flag_base(NP);       // flags per camera
localparam NFLAG = 2 * NFLAG_CAM + 3;

wire [NFLAG-1:0] bad_now;
reg  [NFLAG-1:0] bad_reg = {NFLAG{1'b1}};
reg              all_ok_reg = 1'b0;
reg  [1:0]       wr_shadow_reg = 2'b11;  // shadow writes on the last two edges

genvar g;
generate
    for (c = 0; c < 2; c = c + 1) begin : g_check_cam
        for (p = 0; p < NP; p = p + 1) begin : g_param
            localparam integer W = param_width(p);
            localparam integer NG = param_groups(p);
            localparam integer BASE = c * NFLAG_CAM + flag_base(p);
            localparam [63:0] MIN = param_min(p);
            wire [63:0] value = g_shadow[c].g_param[p].value_reg;

            for (g = 0; g < NG; g = g + 1) begin : g_group
                localparam integer LO = W + CHK_GROUP * g;
                localparam integer HI = LO + CHK_GROUP - 1 > 63 ? 63 : LO + CHK_GROUP - 1;
                assign bad_now[BASE + g] = value[HI:LO] != {(HI-LO+1){value[W-1]}};
            end
            // MIN, if there is one, is > 0: the sign bit must be 0
            assign bad_now[BASE + NG] = MIN != 64'd0 && (value[W-1] || lt_const({{(65-W){1'b0}}, value[W-2:0]}, MIN));
        end
    end
endgenerate

assign bad_now[2*NFLAG_CAM] = width_value == 16'd0 || !lt_const({48'd0, width_value}, {32'd0, MAX_WIDTH_V} + 64'd1);
assign bad_now[2*NFLAG_CAM+1] = height_value == 16'd0 || !lt_const({48'd0, height_value}, {32'd0, MAX_HEIGHT_V} + 64'd1);
assign bad_now[2*NFLAG_CAM+2] = !lt_const({48'd0, lb_delay_value}, {32'd0, MAX_HEIGHT_V});

// The latch: APPLY pending, the datapath idle, and all_ok_reg checked this very shadow set
wire latch = apply_reg && idle && wr_shadow_reg == 2'b00;
wire accept = latch && all_ok_reg;
wire refuse = latch && !all_ok_reg;

always @(posedge clk) begin
    if (wr_shadow_reg[0]) begin
        bad_reg <= bad_now;
    end
    all_ok_reg <= !(|bad_reg);
    wr_shadow_reg <= {wr_shadow_reg[0], wr_shadow};

    if (rst) begin
        wr_shadow_reg <= 2'b11;  // refill the check pipeline
    end
end

/*
 * Next state of the control, status and shadow frame registers
 */
always @* begin
    control_next = control_reg;
    apply_next = apply_reg;
    flags_next = flags_reg;
    frame_count_next = frame_count_reg + {31'd0, frame_done};
    width_next = width_reg;
    height_next = height_reg;
    lb_delay_next = lb_delay_reg;
    debug_row_next = debug_row_reg;

    if (latch) begin
        apply_next = 1'b0;
    end
    if (wr_control) begin
        control_next = merge(control_reg, w_data_reg, w_strb_reg) & CONTROL_RW;
        // APPLY: writing 1 requests a latch (also while one is pending), 0 does nothing
        if (w_mask[`RC_CONTROL_APPLY] && w_data_reg[`RC_CONTROL_APPLY]) begin
            apply_next = 1'b1;
        end
    end
    if (wr_flags) begin
        flags_next = flags_reg & ~(w_data_reg & w_mask);
    end
    // a raise wins over a clear on the same edge
    flags_next = flags_next
        | ({31'd0, set_lb_overflow} << `RC_FLAGS_LB_OVERFLOW)
        | ({31'd0, set_size_error} << `RC_FLAGS_SIZE_ERROR)
        | ({31'd0, refuse} << `RC_FLAGS_CONFIG_ERROR);
    flags_next = flags_next & FLAGS_W1C;
    if (wr_width) begin
        width_next = merge(width_reg, w_data_reg, w_strb_reg) & WIDTH_MASK;
    end
    if (wr_height) begin
        height_next = merge(height_reg, w_data_reg, w_strb_reg) & HEIGHT_MASK;
    end
    if (wr_lb_delay) begin
        lb_delay_next = merge(lb_delay_reg, w_data_reg, w_strb_reg) & LB_DELAY_MASK;
    end
    if (wr_debug_row) begin
        debug_row_next = merge(debug_row_reg, w_data_reg, w_strb_reg) & DEBUG_ROW_MASK;
    end
end

always @(posedge clk) begin
    control_reg <= control_next;
    apply_reg <= apply_next;
    flags_reg <= flags_next;
    frame_count_reg <= frame_count_next;
    width_reg <= width_next;
    height_reg <= height_next;
    lb_delay_reg <= lb_delay_next;
    debug_row_reg <= debug_row_next;

    if (rst) begin
        control_reg <= 32'd0;
        apply_reg <= 1'b0;
        flags_reg <= 32'd0;
        frame_count_reg <= 32'd0;
        width_reg <= WIDTH_RESET;
        height_reg <= HEIGHT_RESET;
        lb_delay_reg <= 32'd0;
        debug_row_reg <= 32'd0;
    end
end

/*
 * Active set: taken from the shadow on an accepted APPLY
 */
reg        applied_reg = 1'b0;
reg [15:0] act_width_reg = WIDTH_RESET[`RC_WIDTH_VALUE +: `RC_WIDTH_VALUE_W];
reg [15:0] act_height_reg = HEIGHT_RESET[`RC_HEIGHT_VALUE +: `RC_HEIGHT_VALUE_W];
reg [15:0] act_lb_delay_reg = 16'd0;
wire [2*SET_W-1:0] act;

always @(posedge clk) begin
    if (accept) begin
        applied_reg <= 1'b1;
        act_width_reg <= width_value;
        act_height_reg <= height_value;
        act_lb_delay_reg <= lb_delay_value;
    end

    if (rst) begin
        applied_reg <= 1'b0;
        act_width_reg <= WIDTH_RESET[`RC_WIDTH_VALUE +: `RC_WIDTH_VALUE_W];
        act_height_reg <= HEIGHT_RESET[`RC_HEIGHT_VALUE +: `RC_HEIGHT_VALUE_W];
        act_lb_delay_reg <= 16'd0;
    end
end

generate
    for (c = 0; c < 2; c = c + 1) begin : g_active_cam
        for (p = 0; p < NP; p = p + 1) begin : g_param
            localparam integer W = param_width(p);
            // a checked value fits W bits: keep those, sign-extend them on the way out
            reg [W-1:0] act_reg = {W{1'b0}};

            always @(posedge clk) begin
                if (accept) begin
                    act_reg <= g_shadow[c].g_param[p].value_reg[W-1:0];
                end
                if (rst) begin
                    act_reg <= {W{1'b0}};
                end
            end

            assign act[c*SET_W + 64*p +: 64] = {{(64-W){act_reg[W-1]}}, act_reg};
        end
    end
endgenerate

assign applied = applied_reg;
assign act_l = act[0 +: SET_W];
assign act_r = act[SET_W +: SET_W];
assign act_width = act_width_reg;
assign act_height = act_height_reg;
assign act_lb_delay = act_lb_delay_reg;
assign ctl_enable = control_reg[`RC_CONTROL_ENABLE];
assign ctl_bypass = control_reg[`RC_CONTROL_BYPASS];
assign ctl_gray = control_reg[`RC_CONTROL_GRAY];
assign ctl_debug_line = control_reg[`RC_CONTROL_DEBUG_LINE];
assign debug_row = debug_row_reg[`RC_DEBUG_ROW_VALUE +: `RC_DEBUG_ROW_VALUE_W];
assign apply_pending = apply_reg;

/*
 * AXI4-Lite read channels: address registered, then decoded into registered data
 */
reg [AW-1:2] ar_addr_reg = {(AW-2){1'b0}};
reg        ar_full_reg = 1'b0, ar_full_next;
reg        s_axil_arready_reg = 1'b0;
reg [31:0] s_axil_rdata_reg = 32'd0;
reg        s_axil_rvalid_reg = 1'b0, s_axil_rvalid_next;

wire rd_load = ar_full_reg && (!s_axil_rvalid_reg || s_axil_rready);

assign s_axil_arready = s_axil_arready_reg;
assign s_axil_rdata = s_axil_rdata_reg;
assign s_axil_rresp = 2'b00;  // OKAY
assign s_axil_rvalid = s_axil_rvalid_reg;

always @* begin
    ar_full_next = ar_full_reg;
    s_axil_rvalid_next = s_axil_rvalid_reg && !s_axil_rready;

    if (rd_load) begin
        ar_full_next = 1'b0;
        s_axil_rvalid_next = 1'b1;
    end
    if (s_axil_arvalid && s_axil_arready_reg) begin
        ar_full_next = 1'b1;
    end
end

always @(posedge clk) begin
    ar_full_reg <= ar_full_next;
    s_axil_arready_reg <= !ar_full_next && !sweeping_next;
    s_axil_rvalid_reg <= s_axil_rvalid_next;

    if (rst) begin
        ar_full_reg <= 1'b0;
        s_axil_arready_reg <= 1'b0;
        s_axil_rvalid_reg <= 1'b0;
    end
end

// read decode: parameter words from the read-back copy
wire [IDX_W-1:0] rd_idx = ar_addr_reg[BLK_LSB-1:2];
wire rd_l = ar_addr_reg[AW-1:BLK_LSB] == BLOCK_L[AW-1:BLK_LSB];
wire rd_r = ar_addr_reg[AW-1:BLK_LSB] == BLOCK_R[AW-1:BLK_LSB];
assign mirror_raddr = {rd_r, rd_idx};
wire [31:0] rd_param = rd_l || rd_r ? rd_mirror : 32'd0;

// what each control register reads (rd_<name>, one per register of RECTIFY_MAP: the
// generated multiplexer below takes them by name)
wire [31:0] rd_id = `RC_CORE_ID;
wire [31:0] rd_version = `RC_CORE_VERSION;
wire [31:0] rd_max_width = MAX_WIDTH_V;
wire [31:0] rd_max_height = MAX_HEIGHT_V;
wire [31:0] rd_lb_rows = LB_ROWS_V;
wire [31:0] rd_caps = {31'd0, COLOUR != 0} << `RC_CAPS_COLOUR;
wire [31:0] rd_control = control_reg | ({31'd0, apply_reg} << `RC_CONTROL_APPLY);
wire [31:0] rd_status = ({31'd0, busy} << `RC_STATUS_BUSY) | ({31'd0, apply_reg} << `RC_STATUS_APPLY_PENDING);
wire [31:0] rd_flags = flags_reg;
wire [31:0] rd_frame_count = frame_count_reg;
wire [31:0] rd_width = width_reg;
wire [31:0] rd_height = height_reg;
wire [31:0] rd_lb_delay = lb_delay_reg;
wire [31:0] rd_debug_row = debug_row_reg;
reg  [31:0] rd_word;  // the control register at ar_addr_reg, 0 elsewhere

// the control registers' write strobes and read multiplexer, generated from RECTIFY_MAP
`include "rc_regs_decode.vh"

always @(posedge clk) begin
    if (s_axil_arvalid && s_axil_arready_reg) begin
        ar_addr_reg <= s_axil_araddr[AW-1:2];
    end
    if (rd_load) begin
        s_axil_rdata_reg <= rd_word | rd_param;
    end
end

// the byte lane bits of the addresses are not used (32-bit registers, WSTRB selects bytes)
// verilator lint_off UNUSEDSIGNAL
wire unused_ok = &{1'b0, s_axil_awaddr[1:0], s_axil_araddr[1:0]};
// verilator lint_on UNUSEDSIGNAL

endmodule

`resetall
