// Language: Verilog 2005

`include "prelude.vh"

`include "rectify_spec.vh"

/*
 * rc_interp: step 5 of RECTIFY_CORE.md for one 8-bit channel, bilinear
 * interpolation of the four taps G0 = (x0, y0), G1 = (x0+1, y0),
 * G2 = (x0, y0+1), G3 = (x0+1, y0+1) with RC_FRAC_BITS-bit fractions:
 *
 *   out = ((32-dv)*((32-du)*G0 + du*G1) + dv*((32-du)*G2 + du*G3) + 512) >> 10
 *
 * computed exactly as
 *
 *   A = 32*G0 + du*(G1 - G0),  B = 32*G2 + du*(G3 - G2)
 *   out = (32*(A + 16) + dv*(B - A)) >> 10
 *
 * (the same integers: (32-du)*G0 + du*G1 = 32*G0 + du*(G1-G0), and 32*16 is
 * the rounding 512). The products by the 5-bit fractions are sums of shifted
 * partial products (du[i] ? d << i : 0) added in balanced trees, so no tool
 * makes a DSP of them (yosys 0.23 ignores use_dsp; the attribute is for
 * Vivado) and no stage has more than two adders in series.
 *
 * Latency: LATENCY = 6 clocks (rc_datapath counts on it). Throughput: 1 per
 * clock, never stalls, no reset (data only; the caller carries valid bits).
 */
module rc_interp
(
    input  wire                     clk,
    input  wire [7:0]               g0,
    input  wire [7:0]               g1,
    input  wire [7:0]               g2,
    input  wire [7:0]               g3,
    input  wire [`RC_FRAC_BITS-1:0] du,
    input  wire [`RC_FRAC_BITS-1:0] dv,
    output wire [7:0]               out
);

localparam FB = `RC_FRAC_BITS;               // 5: fraction bits
localparam WB = `RC_WEIGHT_BITS;             // 10: bits of the weights' sum
localparam DW = 9;                           // G1 - G0: signed
localparam HW = 8 + FB + 1;                  // A, B, B - A, A + 16: signed, |.| <= 255 * 32 + 16
localparam VW = HW + FB + 1;                 // 32*(A+16) + dv*(B-A): signed

// partial product i of u * d: d << i when bit i of u is set
function signed [HW-1:0] pp_h;
    input u_bit;
    input signed [DW-1:0] d;
    input integer i;
    reg signed [HW-1:0] de;
    begin
        de = {{HW-DW{d[DW-1]}}, d};
        pp_h = u_bit ? de <<< i : {HW{1'b0}};
    end
endfunction

function signed [VW-1:0] pp_v;
    input u_bit;
    input signed [HW-1:0] d;
    input integer i;
    reg signed [VW-1:0] de;
    begin
        de = {{VW-HW{d[HW-1]}}, d};
        pp_v = u_bit ? de <<< i : {VW{1'b0}};
    end
endfunction

// stage 1: horizontal differences
(* use_dsp = "no" *) reg signed [DW-1:0] d01_1_reg, d23_1_reg;
reg [7:0]    g0_1_reg, g2_1_reg;
reg [FB-1:0] du_1_reg, dv_1_reg;

// stage 2: first level of the horizontal sums (A: a*, B: b*)
(* use_dsp = "no" *) reg signed [HW-1:0] a01_2_reg, a23_2_reg, a4_2_reg, b01_2_reg, b23_2_reg, b4_2_reg;
reg [FB-1:0] dv_2_reg;

// stage 3: A and B
(* use_dsp = "no" *) reg signed [HW-1:0] a_3_reg, b_3_reg;
reg [FB-1:0] dv_3_reg;

// stage 4: B - A and A + 16
(* use_dsp = "no" *) reg signed [HW-1:0] dba_4_reg, a16_4_reg;
reg [FB-1:0] dv_4_reg;

// stage 5: first level of the vertical sum
(* use_dsp = "no" *) reg signed [VW-1:0] v01_5_reg, v23_5_reg, v4_5_reg;

// stage 6: the result
(* use_dsp = "no" *) reg signed [VW-1:0] sum_6_reg;

wire signed [HW-1:0] g0_32 = $signed({1'b0, g0_1_reg, {FB{1'b0}}});
wire signed [HW-1:0] g2_32 = $signed({1'b0, g2_1_reg, {FB{1'b0}}});
wire signed [VW-1:0] a16_32 = {{VW-HW-FB{a16_4_reg[HW-1]}}, a16_4_reg, {FB{1'b0}}};

always @(posedge clk) begin
    d01_1_reg <= $signed({1'b0, g1}) - $signed({1'b0, g0});
    d23_1_reg <= $signed({1'b0, g3}) - $signed({1'b0, g2});
    g0_1_reg <= g0;
    g2_1_reg <= g2;
    du_1_reg <= du;
    dv_1_reg <= dv;

    a01_2_reg <= pp_h(du_1_reg[0], d01_1_reg, 0) + pp_h(du_1_reg[1], d01_1_reg, 1);
    a23_2_reg <= pp_h(du_1_reg[2], d01_1_reg, 2) + pp_h(du_1_reg[3], d01_1_reg, 3);
    a4_2_reg <= pp_h(du_1_reg[4], d01_1_reg, 4) + g0_32;
    b01_2_reg <= pp_h(du_1_reg[0], d23_1_reg, 0) + pp_h(du_1_reg[1], d23_1_reg, 1);
    b23_2_reg <= pp_h(du_1_reg[2], d23_1_reg, 2) + pp_h(du_1_reg[3], d23_1_reg, 3);
    b4_2_reg <= pp_h(du_1_reg[4], d23_1_reg, 4) + g2_32;
    dv_2_reg <= dv_1_reg;

    a_3_reg <= (a01_2_reg + a23_2_reg) + a4_2_reg;
    b_3_reg <= (b01_2_reg + b23_2_reg) + b4_2_reg;
    dv_3_reg <= dv_2_reg;

    dba_4_reg <= b_3_reg - a_3_reg;
    a16_4_reg <= a_3_reg + $signed({{HW-FB{1'b0}}, 1'b1, {FB-1{1'b0}}});
    dv_4_reg <= dv_3_reg;

    v01_5_reg <= pp_v(dv_4_reg[0], dba_4_reg, 0) + pp_v(dv_4_reg[1], dba_4_reg, 1);
    v23_5_reg <= pp_v(dv_4_reg[2], dba_4_reg, 2) + pp_v(dv_4_reg[3], dba_4_reg, 3);
    v4_5_reg <= pp_v(dv_4_reg[4], dba_4_reg, 4) + a16_32;

    sum_6_reg <= (v01_5_reg + v23_5_reg) + v4_5_reg;
end

assign out = sum_6_reg[WB +: 8];

// the sum is 0 .. 255 * 1024 + 512: the bits above the result are 0, those below are dropped
// verilator lint_off UNUSEDSIGNAL
wire unused_ok = &{1'b0, sum_6_reg};
// verilator lint_on UNUSEDSIGNAL

endmodule

`resetall
