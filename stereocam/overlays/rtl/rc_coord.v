// rc_coord: the coordinate engine, steps 1-4 of RECTIFY_CORE.md for both cameras.
//
// For every output pixel (x, y) of a width x height frame, in raster order, one output
// word: the source positions (iu, iv) of the left and of the right camera in 1/32 px and
// whether each is valid (ok; when 0, iu = iv = 0). Bit for bit stereocam/overlays/model/fixed.py.
//
// One pipeline, shared by the cameras: the left camera enters on one clock, the right on
// the next, so a pixel takes 2 clocks (throughput one word per 2 clocks while out_ready
// allows). The pipeline never stalls: a pixel is issued only when the output FIFO has a
// free place for it counting every pixel already in flight (credits), so out_ready low
// only holds words in the FIFO and, once it is full, stops the issue.
//
// Latency: a pixel whose left camera enters between clock edges c and c + 1 has its word on
// out_valid from edge c + 62 on (S_IU = 60 stages per camera, one clock to pair the right
// camera with the left, one to write the FIFO). `start` taken at edge 0 loads the frame;
// its first pixel enters at once or a clock later (the left camera enters on even clocks
// of a free-running phase), so the first word is on out_valid from edge 62 or 63.
// The output FIFO (FIFO_DEPTH words, distributed RAM, first-word fall-through) absorbs
// out_ready low; with out_ready high the words come one every 2 clocks without a gap.
//
// Frame and line boundaries: `start` is taken only while no pixel of a previous frame
// remains to be issued (words of that frame may still be in the pipeline or the FIFO;
// they come out first); a start with width or height 0 is ignored. par_l, par_r must hold
// from start until the frame's last word has left (they are read at every stage, not
// copied); width and height (each at most 2**RC_SIZE_W) are copied at start. Lines need
// nothing special: the row accumulators step at the first pixel of each row, so pixels
// flow across line ends and from one frame to the next without a gap.
//
// Step 1 keeps per camera two accumulators per coordinate, modulo 2**RC_ACC_W: the value
// for the next pixel of the row and the value at the start of the next row; a pixel at
// x = 0 takes the row value (N02, N12, N22 in row 0) and leaves it + N01 (N11, N21) for
// the next row, every pixel leaves its own value + N00 (N10, N20) for the next pixel.
// Step 2 divides |X| and |Y| by Z in rc_div (33 stages, one quotient bit each, Z shared)
// and rounds and signs the quotients on their way into the products. Steps 2-4 follow
// the equations with thirteen rc_coord_mul products (four DSP48E1 each); each rounding
// rnd(v, s) and the addend that follows it share one adder. Validity: a pixel failing a
// check keeps flowing with meaningless values and an ok bit of 0 that travels beside it;
// the last stage forces iu = iv = 0 then.
//
// Stages (a sample is in stage k k clocks after it entered): 0 accumulators, 1 |X| |Y| Z,
// 2..34 divider, 34 quotients -> xn yn -> 39 x2 y2 xy -> 40 r2 -> 45 s -> 50 radial ->
// 55 xd yd -> 60 iu iv, checked into the FIFO. Clocks: one, `clk`; reset `rst`
// (synchronous, active high) clears the control and the FIFO, not the datapath.
`include "rectify_spec.vh"

`include "prelude.vh"

module rc_coord #(
    parameter FIFO_DEPTH = 32     // output words buffered; at least FIFO_MIN (32), the words in flight at full rate
) (
    input  wire clk,
    input  wire rst,
    input  wire start,
    /* verilator lint_off UNUSEDSIGNAL */     // only the low RC_<NAME>_W bits of each value are used
    input  wire [`RC_NPARAMS*64-1:0] par_l,
    input  wire [`RC_NPARAMS*64-1:0] par_r,
    /* verilator lint_on UNUSEDSIGNAL */
    input  wire [15:0] width,
    input  wire [15:0] height,
    output wire out_valid,
    input  wire out_ready,
    output wire signed [`RC_POS_W-1:0] iu_l,
    output wire signed [`RC_POS_W-1:0] iv_l,
    output wire signed [`RC_POS_W-1:0] iu_r,
    output wire signed [`RC_POS_W-1:0] iv_r,
    output wire ok_l,
    output wire ok_r
);
    // ---- formats (all from the spec header) ------------------------------------------------
    localparam F   = `RC_F;
    localparam AW  = `RC_ACC_W;               // accumulators
    localparam NW  = `RC_N00_W;               // homography entries
    localparam QB  = `RC_DIV_QBITS;           // quotient bits
    localparam XW  = `RC_W_XN;
    localparam X2W = `RC_W_X2;
    localparam XYW = `RC_W_XY;
    localparam R2W = `RC_W_R2;
    localparam SW  = `RC_W_S;
    localparam MW  = `RC_W_M;
    localparam RAW = `RC_W_RADIAL;
    localparam AXW = `RC_W_A;
    localparam XY2W = `RC_W_XY2;
    localparam QW  = `RC_W_Q;
    localparam CW  = `RC_W_C;
    localparam XDW = `RC_W_XD;
    localparam XDFW = AXW + 1;                // xd = a + c12 before its check (|c12| < 2**(CW-1))
    localparam UW  = `RC_W_SU - `RC_SU_SHIFT; // iu before its check
    localparam PW  = `RC_POS_W;
    localparam KW  = `RC_K1_W;
    localparam PPW = `RC_P1_W;
    localparam FXW = `RC_FX_W;
    localparam CXW = `RC_CX_W;
    localparam KF  = `RC_K1_FRAC;
    localparam PF  = `RC_P1_FRAC;
    localparam CNT = `RC_SIZE_W;              // column and row counters
    localparam RES = 2 * PW + 1;              // one camera's result: {ok, iv, iu}

    // Validity limits, as values of the widths they are compared in.
    localparam [AW+2:0]   ZMUL    = `RC_XN_LIMIT;                                  // |X| < 4 Z
    localparam [X2W:0]    R2_ONE  = {{X2W{1'b0}}, 1'b1} << F;
    localparam [X2W:0]    R2_LIM  = R2_ONE * `RC_R2_LIMIT;                         // r2 < 8 * 2**F
    localparam [MW-1:0]   RAD_ONE = {{MW-1{1'b0}}, 1'b1} << F;
    localparam [MW-1:0]   RAD_LIM = RAD_ONE * `RC_RADIAL_LIMIT;                     // |radial| < 8 * 2**F
    localparam [XDFW-1:0] XD_ONE  = {{XDFW-1{1'b0}}, 1'b1} << F;
    localparam [XDFW-1:0] XD_LIM  = XD_ONE * `RC_XD_LIMIT;                         // |xd| < 16 * 2**F
    localparam [UW-1:0]   POS_LIM = `RC_COORD_LIMIT;                               // |iu| < 2**20

    // ---- pipeline stages: a sample is in stage k k clocks after it entered ---------------
    localparam LM    = 5;                     // rc_coord_mul latency
    localparam S_ABS = 1;                     // |X|, |Y|, Z
    localparam S_DIV = S_ABS + QB;            // quotients
    localparam S_XN  = S_DIV;                 // xn, yn (rounded and signed on their way into the products)
    localparam S_SQ  = S_XN + LM;             // x2, y2, xy
    localparam S_R2  = S_SQ + 1;              // r2 (its check enters ok at S_R2 + 1)
    localparam S_S   = S_R2 + LM;             // s = K1 + t
    localparam S_RAD = S_S + LM;              // radial
    localparam S_XD  = S_RAD + LM;            // xd, yd
    localparam S_IU  = S_XD + LM;             // iu, iv before their check; checked on their way to the FIFO
    // A credit comes back S_IU + 3 clocks after its pixel entered (the right camera one clock
    // later, the FIFO write, the pop) and is used on the next even clock: with one pixel every
    // 2 clocks, this many credits keep the issue going at full rate.
    localparam FIFO_MIN = (S_IU + 3 + 1) / 2;
    generate
        if (FIFO_DEPTH < FIFO_MIN) begin : fifo_too_small
            rc_coord_fifo_depth_below_fifo_min error ();   // no such module: stops elaboration
        end
    endgenerate

    // ---- parameters: the low bits of each signed 64-bit value --------------------------------
    wire [NW-1:0] n_l [0:8];
    wire [NW-1:0] n_r [0:8];
    genvar i;
    generate
        for (i = 0; i < 9; i = i + 1) begin : npar
            assign n_l[i] = par_l[64 * (`RC_P_N00 + i) +: NW];
            assign n_r[i] = par_r[64 * (`RC_P_N00 + i) +: NW];
        end
    endgenerate

    // The camera of the sample in stage k: the left camera enters when ph = 0, so a sample
    // in an even stage belongs to camera ph and one in an odd stage to camera !ph.
    // ~900 loads (every stage's camera select): replicated by Vivado's synthesis, 64 loads a copy at most
    (* max_fanout = 64 *) reg ph;
    wire cam_even = ph;
    wire cam_odd  = ~ph;
`define RC_CAM(k) ((((k) % 2) != 0) ? cam_odd : cam_even)
`define RC_PAR(k, idx, w) (`RC_CAM(k) ? par_r[64 * (idx) +: (w)] : par_l[64 * (idx) +: (w)])

    // ---- issue: frame and pixel sequencing, credits --------------------------------------------
    reg             run;          // pixels of the frame remain to be issued
    reg [CNT-1:0]   col, row, last_col, last_row;
    reg             x0;           // col == 0
    reg             y0;           // row == 0
    reg             issue_r;      // the right camera of the pixel whose left one entered last clock
    localparam CRW = $clog2(FIFO_DEPTH + 1);
    reg [CRW-1:0]   credits;
    wire            pop = out_valid && out_ready;
    wire            load = start && !run && !issue_r && width != 16'd0 && height != 16'd0;
    wire            issue_l = run && !ph && credits != 0;
    wire            issue = issue_l || issue_r;
    /* verilator lint_off UNUSEDSIGNAL */     // frames are at most 2**RC_SIZE_W pixels wide and high
    wire [15:0]     width_m1 = width - 16'd1;
    wire [15:0]     height_m1 = height - 16'd1;
    /* verilator lint_on UNUSEDSIGNAL */

    always @(posedge clk) begin
        if (rst) begin
            ph <= 1'b0;
            run <= 1'b0;
            issue_r <= 1'b0;
            credits <= FIFO_DEPTH;
        end else begin
            ph <= ~ph;
            issue_r <= issue_l;
            credits <= credits - {{CRW-1{1'b0}}, issue_l} + {{CRW-1{1'b0}}, pop};
            if (load) run <= 1'b1;
            else if (issue_r && col == last_col && row == last_row) run <= 1'b0;
        end
    end

    always @(posedge clk) begin
        if (load) begin
            last_col <= width_m1[CNT-1:0];
            last_row <= height_m1[CNT-1:0];
            col <= {CNT{1'b0}};
            row <= {CNT{1'b0}};
            x0 <= 1'b1;
            y0 <= 1'b1;
        end else if (issue_r) begin
            if (col == last_col) begin
                col <= {CNT{1'b0}};
                row <= row + 1'b1;
                x0 <= 1'b1;
                y0 <= 1'b0;
            end else begin
                col <= col + 1'b1;
                x0 <= 1'b0;
            end
        end
    end

    // ---- step 1: X, Y, Z accumulators, stage 0 -------------------------------------------------
    wire [3*AW-1:0] acc;      // X, Y, Z of the sample entering now (camera ph)
    genvar r;
    generate
        for (r = 0; r < 3; r = r + 1) begin : step1
            reg  [AW-1:0] cur_l, cur_r;   // value of the next pixel in the row
            reg  [AW-1:0] nxt_l, nxt_r;   // value at the start of the next row (row 0: N02 itself)
            wire [NW-1:0] nx = ph ? n_r[3*r] : n_l[3*r];          // N00 (N10, N20)
            wire [NW-1:0] ny = ph ? n_r[3*r+1] : n_l[3*r+1];      // N01
            wire [NW-1:0] nc = ph ? n_r[3*r+2] : n_l[3*r+2];      // N02
            wire [AW-1:0] row_v = y0 ? {{AW-NW{nc[NW-1]}}, nc} : (ph ? nxt_r : nxt_l);
            wire [AW-1:0] v = x0 ? row_v : (ph ? cur_r : cur_l);
            wire [AW-1:0] v_dx = v + {{AW-NW{nx[NW-1]}}, nx};
            wire [AW-1:0] v_dy = v + {{AW-NW{ny[NW-1]}}, ny};
            always @(posedge clk) begin
                if (issue && x0) begin
                    if (ph) nxt_r <= v_dy;
                    else nxt_l <= v_dy;
                end
                if (issue) begin
                    if (ph) cur_r <= v_dx;
                    else cur_l <= v_dx;
                end
            end
            assign acc[r*AW +: AW] = v;
        end
    endgenerate

    // ---- stage 1: |X|, |Y|, signs, Z ------------------------------------------------------------
    wire [AW-1:0] x_s0 = acc[0 +: AW];
    wire [AW-1:0] y_s0 = acc[AW +: AW];
    reg  [AW-1:0] ax1, ay1, z1;     // |X|, |Y| unsigned (|-2**47| = 2**47 fits)
    reg           sx1, sy1;
    always @(posedge clk) begin
        ax1 <= (x_s0 ^ {AW{x_s0[AW-1]}}) + x_s0[AW-1];
        ay1 <= (y_s0 ^ {AW{y_s0[AW-1]}}) + y_s0[AW-1];
        sx1 <= x_s0[AW-1];
        sy1 <= y_s0[AW-1];
        z1 <= acc[2*AW +: AW];
    end

    // The check of step 1 (enters ok at stage 2): Z > 0, |X| < 4 Z, |Y| < 4 Z.
    wire [AW+2:0] z4 = {3'b000, z1[AW-2:0]} * ZMUL;
    wire ok1 = !z1[AW-1] && z1 != {AW{1'b0}} && {3'b000, ax1} < z4 && {3'b000, ay1} < z4;

    // ---- step 2: divide (stages 2..S_DIV), round and sign (S_XN) ---------------------------------
    wire [2*QB-1:0] quo;
    rc_div #(.LANES(2), .NW(AW), .DW(AW - 1), .QB(QB), .SH(F + 1)) div (
        .clk(clk), .num({ay1, ax1}), .den(z1[AW-2:0]), .quo(quo));
    wire [1:0] sgn_div;
    rc_coord_delay #(.W(1), .N(S_DIV - S_ABS)) sx_delay (.clk(clk), .d(sx1), .q(sgn_div[0]));
    rc_coord_delay #(.W(1), .N(S_DIV - S_ABS)) sy_delay (.clk(clk), .d(sy1), .q(sgn_div[1]));

    // div = sign * ((q + 1) >> 1) = (h ^ s) + (q0 ^ s) with h = q >> 1: one adder on the way
    // from the quotient register into the products' input registers.
    wire signed [XW-1:0] xn = ({{XW-QB+1{1'b0}}, quo[1 +: QB-1]} ^ {XW{sgn_div[0]}})
                            + {{XW-1{1'b0}}, quo[0] ^ sgn_div[0]};
    wire signed [XW-1:0] yn = ({{XW-QB+1{1'b0}}, quo[QB+1 +: QB-1]} ^ {XW{sgn_div[1]}})
                            + {{XW-1{1'b0}}, quo[QB] ^ sgn_div[1]};

    // x2 = rnd(xn*xn, F), y2 = rnd(yn*yn, F), xy = rnd(xn*yn, F): stage S_SQ.
    wire signed [X2W-1:0] x2, y2;
    wire signed [XYW-1:0] xy;
    rc_coord_mul #(.AW(XW), .BW(XW), .LO(F - 1), .CW(2), .SH(1), .OW(X2W))
        mul_xx (.clk(clk), .a(xn), .b(xn), .c(2'sd1), .p(x2));
    rc_coord_mul #(.AW(XW), .BW(XW), .LO(F - 1), .CW(2), .SH(1), .OW(X2W))
        mul_yy (.clk(clk), .a(yn), .b(yn), .c(2'sd1), .p(y2));
    rc_coord_mul #(.AW(XW), .BW(XW), .LO(F - 1), .CW(2), .SH(1), .OW(XYW))
        mul_xy (.clk(clk), .a(xn), .b(yn), .c(2'sd1), .p(xy));

    // r2 = x2 + y2 (stage S_R2; x2, y2 >= 0), its check enters ok at S_R2 + 1.
    reg [X2W:0]   r2_full;
    reg [R2W-1:0] x2_r2, y2_r2;        // x2, y2 at S_R2 (fit R2W bits when r2 passes)
    always @(posedge clk) begin
        r2_full <= {x2[X2W-1], x2} + {y2[X2W-1], y2};
        x2_r2 <= x2[R2W-1:0];
        y2_r2 <= y2[R2W-1:0];
    end
    wire ok2 = r2_full < R2_LIM;
    wire signed [R2W-1:0] r2 = r2_full[R2W-1:0];

    // ---- step 3 --------------------------------------------------------------------------------
    // s = rnd(K2*r2, F) + K1: stage S_S; K1 is taken with the product's last register.
    reg  [KW:0] k1_c;
    always @(posedge clk) k1_c <= {`RC_PAR(S_S - 2, `RC_P_K1, KW), 1'b1};
    wire signed [SW-1:0] s;
    rc_coord_mul #(.AW(KW), .BW(R2W), .LO(F - 1), .CW(KW + 1), .SH(1), .OW(SW))
        mul_s (.clk(clk), .a(`RC_PAR(S_R2, `RC_P_K2, KW)), .b(r2), .c(k1_c), .p(s));

    // radial = 2**F + rnd(s*r2, KF): stage S_RAD, check enters ok at S_RAD + 1.
    wire signed [R2W-1:0] r2_s;
    rc_coord_delay #(.W(R2W), .N(S_S - S_R2)) r2_delay (.clk(clk), .d(r2), .q(r2_s));
    localparam [F+2:0] RAD_C = ({{F+2{1'b0}}, 1'b1} << (F + 1)) | 1;
    wire signed [MW-1:0] radial_full;
    rc_coord_mul #(.AW(SW), .BW(R2W), .LO(KF - 1), .CW(F + 3), .SH(1), .OW(MW))
        mul_radial (.clk(clk), .a(s), .b(r2_s), .c(RAD_C), .p(radial_full));
    wire ok3 = $signed(radial_full) < $signed(RAD_LIM) && $signed(radial_full) > -$signed(RAD_LIM);

    // Tangential terms, summed as they are made: cx12 = rnd(P1*2xy, PF) + rnd(P2*(r2 + 2 x2), PF),
    // cy12 = rnd(P2*2xy, PF) + rnd(P1*(r2 + 2 y2), PF); stage S_R2 + LM.
    // 2xy enters as xy with LO one lower (the same integers): a constant-zero low bit in the
    // DSPs' A port would stop yosys 0.23 cascading the product (rc_coord_mul.v, dsp_map.py).
    wire signed [CW-1:0] cx1, cy1, cx12, cy12;
    rc_coord_mul #(.AW(XY2W - 1), .BW(PPW), .LO(PF - 2), .CW(2), .SH(1), .OW(CW))
        mul_cx1 (.clk(clk), .a(xy), .b(`RC_PAR(S_SQ, `RC_P_P1, PPW)), .c(2'sd1), .p(cx1));
    rc_coord_mul #(.AW(XY2W - 1), .BW(PPW), .LO(PF - 2), .CW(2), .SH(1), .OW(CW))
        mul_cy1 (.clk(clk), .a(xy), .b(`RC_PAR(S_SQ, `RC_P_P2, PPW)), .c(2'sd1), .p(cy1));
    wire signed [QW-1:0] qx = {{QW-R2W{1'b0}}, r2} + {{QW-R2W-1{1'b0}}, x2_r2, 1'b0};
    wire signed [QW-1:0] qy = {{QW-R2W{1'b0}}, r2} + {{QW-R2W-1{1'b0}}, y2_r2, 1'b0};
    rc_coord_mul #(.AW(QW), .BW(PPW), .LO(PF - 1), .CW(CW + 1), .SH(1), .OW(CW))
        mul_cx2 (.clk(clk), .a(qx), .b(`RC_PAR(S_R2, `RC_P_P2, PPW)), .c({cx1, 1'b1}), .p(cx12));
    rc_coord_mul #(.AW(QW), .BW(PPW), .LO(PF - 1), .CW(CW + 1), .SH(1), .OW(CW))
        mul_cy2 (.clk(clk), .a(qy), .b(`RC_PAR(S_R2, `RC_P_P1, PPW)), .c({cy1, 1'b1}), .p(cy12));

    // xd = rnd(xn*radial, F) + cx12, yd likewise: stage S_XD, check enters ok at S_XD + 1.
    wire signed [XW-1:0] xn_rad, yn_rad;
    rc_coord_delay #(.W(XW), .N(S_RAD - S_XN)) xn_delay (.clk(clk), .d(xn), .q(xn_rad));
    rc_coord_delay #(.W(XW), .N(S_RAD - S_XN)) yn_delay (.clk(clk), .d(yn), .q(yn_rad));
    wire signed [CW-1:0] cx12_d, cy12_d;
    rc_coord_delay #(.W(CW), .N(S_XD - 1 - (S_R2 + LM))) cx12_delay (.clk(clk), .d(cx12), .q(cx12_d));
    rc_coord_delay #(.W(CW), .N(S_XD - 1 - (S_R2 + LM))) cy12_delay (.clk(clk), .d(cy12), .q(cy12_d));
    wire signed [RAW-1:0] radial = radial_full[RAW-1:0];
    wire signed [XDFW-1:0] xd_full, yd_full;
    rc_coord_mul #(.AW(XW), .BW(RAW), .LO(F - 1), .CW(CW + 1), .SH(1), .OW(XDFW))
        mul_xd (.clk(clk), .a(xn_rad), .b(radial), .c({cx12_d, 1'b1}), .p(xd_full));
    rc_coord_mul #(.AW(XW), .BW(RAW), .LO(F - 1), .CW(CW + 1), .SH(1), .OW(XDFW))
        mul_yd (.clk(clk), .a(yn_rad), .b(radial), .c({cy12_d, 1'b1}), .p(yd_full));
    wire ok4 = $signed(xd_full) < $signed(XD_LIM) && $signed(xd_full) > -$signed(XD_LIM)
            && $signed(yd_full) < $signed(XD_LIM) && $signed(yd_full) > -$signed(XD_LIM);

    // ---- step 4: iu = rnd(FX*xd + CX*2**F, SU_SHIFT) = ((FX*xd >>> F) + CX + 2**(SU_SHIFT-F-1)) >>> (SU_SHIFT-F)
    localparam USH = `RC_SU_SHIFT - F;
    localparam [CXW:0] U_ROUND = {{CXW{1'b0}}, 1'b1} << (USH - 1);
    wire [CXW-1:0] cx_p = `RC_PAR(S_IU - 2, `RC_P_CX, CXW);
    wire [CXW-1:0] cy_p = `RC_PAR(S_IU - 2, `RC_P_CY, CXW);
    reg  [CXW:0]   cx_c, cy_c;
    always @(posedge clk) begin
        cx_c <= {cx_p[CXW-1], cx_p} + U_ROUND;
        cy_c <= {cy_p[CXW-1], cy_p} + U_ROUND;
    end
    wire signed [XDW-1:0] xd = xd_full[XDW-1:0];
    wire signed [XDW-1:0] yd = yd_full[XDW-1:0];
    wire signed [UW-1:0] iu_full, iv_full;
    rc_coord_mul #(.AW(FXW), .BW(XDW), .LO(F), .CW(CXW + 1), .SH(USH), .OW(UW))
        mul_iu (.clk(clk), .a(`RC_PAR(S_XD, `RC_P_FX, FXW)), .b(xd), .c(cx_c), .p(iu_full));
    rc_coord_mul #(.AW(FXW), .BW(XDW), .LO(F), .CW(CXW + 1), .SH(USH), .OW(UW))
        mul_iv (.clk(clk), .a(`RC_PAR(S_XD, `RC_P_FY, FXW)), .b(yd), .c(cy_c), .p(iv_full));
    wire ok5 = $signed(iu_full) < $signed(POS_LIM) && $signed(iu_full) > -$signed(POS_LIM)
            && $signed(iv_full) < $signed(POS_LIM) && $signed(iv_full) > -$signed(POS_LIM);

    // ---- validity: one bit beside the sample, cleared by each failing check ----------------------
    reg [S_IU:2] okc;     // okc[k]: the sample in stage k passed every check so far
    always @(posedge clk) begin
        okc <= {okc[S_IU-1:2], ok1};          // one shift (a loop of bit copies simulates slowly)
        okc[S_R2 + 1] <= okc[S_R2] & ok2;
        okc[S_RAD + 1] <= okc[S_RAD] & ok3;
        okc[S_XD + 1] <= okc[S_XD] & ok4;
    end

    // ---- stage S_IU: one camera's checked result; the left one waits a clock for the right one
    wire          ok_out = okc[S_IU] & ok5;
    wire [RES-1:0] res = ok_out ? {1'b1, iv_full[PW-1:0], iu_full[PW-1:0]} : {RES{1'b0}};
    reg  [RES-1:0] res_l;
    always @(posedge clk) res_l <= res;

    // Which stages hold a left-camera sample of an issued pixel (reset: nothing in flight).
    reg [S_IU+1:1] vld;
    always @(posedge clk) begin
        if (rst) vld <= {S_IU+1{1'b0}};
        else vld <= {vld[S_IU:1], issue_l};
    end

    // ---- output FIFO: a pixel's word goes in when its right camera is in stage S_IU ----------
    wire [2*RES-1:0] word;
    /* verilator lint_off PINCONNECTEMPTY */  // credits, not s_ready or count, keep it from overflowing
    rc_fifo #(.WIDTH(2 * RES), .DEPTH(FIFO_DEPTH), .SHOW_AHEAD(1)) fifo (
        .clk(clk), .rst(rst),
        .s_data({res, res_l}), .s_valid(vld[S_IU+1]), .s_ready(),
        .m_data(word), .m_valid(out_valid), .m_ready(out_ready), .count());
    /* verilator lint_on PINCONNECTEMPTY */
    assign iu_l = word[0 +: PW];
    assign iv_l = word[PW +: PW];
    assign ok_l = word[2*PW];
    assign iu_r = word[RES +: PW];
    assign iv_r = word[RES + PW +: PW];
    assign ok_r = word[RES + 2*PW];

`undef RC_CAM
`undef RC_PAR
endmodule

`resetall
