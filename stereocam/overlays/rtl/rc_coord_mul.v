// rc_coord_mul: one rounded product of the coordinate engine, p = ((a * b) >>> LO + c) >>> SH.
//
// With LO = S - 1, c = 2 d + 1 and SH = 1 this is rnd(a * b, S) + d of RECTIFY_CORE.md: the
// rounding bit and an addend cost one adder together.
//
// The product is four DSP48E1 in one cascade, written out register by register so that
// synthesis maps it exactly so, every register inside a DSP48E1 (yosys 0.23 does, in every
// one of the core's thirteen products; Vivado could not be run here): with a = a1 2**17 + a0
// and b = b1 2**17 + b0 (a0, b0 the unsigned 17 low bits),
//   DSP1  m1 = a0 b0                                        AREG>=1 BREG>=1 MREG
//   DSP2  h1 = a0 b1 + (m1 >>> 17)            (PCIN >> 17)  AREG>=1 BREG>=1 MREG PREG
//   DSP3  d3 = a1 b0 + h1                     (PCIN)        AREG=2 BREG=2 MREG
//   DSP4  h2 = a1 b1 + (d3 >>> 17)            (PCIN >> 17)  AREG=2 BREG=2 MREG PREG
// (AREG>=1: a_r, and a register in front of the product when the caller has one, which
// synthesis takes into the DSP as A1REG; BREG likewise. No P goes through fabric into a C.
// stereocam/overlays/rtl/dsp_map.py reads this table and tests/overlays/test_dsp_map.py holds
// the synthesised core's DSP48E1 cells against it.) So a b = h2 2**34 + d3[16:0] 2**17
// + m1[16:0]. Every path is one multiply or one post-adder and a cascade between registers;
// a*b needs AW <= 42 and BW <= 35 (a1 fits the 25-bit A port, b1 the 18-bit B port), both at
// least 18. Then one fabric adder takes the
// product bits from LO up (LO >= 17), adds c and drops SH more bits into the registered p.
//
// p is truncated to OW bits (two's complement): the caller chooses OW so that every value
// of interest fits. Latency 5 clocks from a, b (a, b registered on entry; two register
// stages after each multiply, MREG and PREG, then p); c is taken 4 clocks after a, b (it
// must come from a register then). Throughput one product per clock, no handshake, no
// reset: it knows nothing of frames or lines.
`include "prelude.vh"

module rc_coord_mul #(
    parameter AW = 34,      // signed width of a, 18..42
    parameter BW = 34,      // signed width of b, 18..35
    parameter LO = 29,      // product bits below LO are dropped before the add (>= 17)
    parameter CW = 2,       // signed width of c
    parameter SH = 1,       // bits dropped after the add
    parameter OW = 36       // signed width of p
) (
    input  wire                 clk,
    input  wire signed [AW-1:0] a,
    input  wire signed [BW-1:0] b,
    input  wire signed [CW-1:0] c,
    output reg  signed [OW-1:0] p
);
    localparam SW = OW + SH;                 // adder width: the bits p is made of
    localparam HW = AW + BW - 17;            // width of a*b >>> 17
    localparam XW = (LO - 17 + SW > HW) ? LO - 17 + SW : HW;

    generate
        if (AW < 18 || AW > 42 || BW < 18 || BW > 35 || LO < 17) begin : bad_parameters
            rc_coord_mul_parameters_out_of_range error ();   // no such module: stops elaboration
        end
    endgenerate

    reg  signed [AW-1:0]    a_r;
    reg  signed [BW-1:0]    b_r;
    wire signed [17:0]      a0 = {1'b0, a_r[16:0]};
    wire signed [17:0]      b0 = {1'b0, b_r[16:0]};
    wire signed [AW-18:0]   a1 = a_r[AW-1:17];
    wire signed [BW-18:0]   b1 = b_r[BW-1:17];
    reg  signed [AW-18:0]   a1_d;           // DSP3, DSP4: their inputs one clock later
    reg  signed [17:0]      b0_d;
    reg  signed [BW-18:0]   b1_d;
    // Exact widths, not 48: with 48-bit registers yosys 0.23 finds the PCIN cascades or not
    // depending on its cell order, and a product then costs some 50 LUT and 50 FF more.
    localparam W1 = 36;                     // m1 = a0 b0 < 2**34
    localparam W2 = BW + 1;                 // m2 = a0 b1, |m2| <= 2**(BW-1)
    localparam WH1 = BW + 2;                // h1 = m2 + (m1 >>> 17)
    localparam W3 = AW + 1;                 // m3 = a1 b0, |m3| <= 2**(AW-1)
    localparam WD3 = ((W3 > WH1) ? W3 : WH1) + 1;
    localparam W4 = AW + BW - 34;           // m4 = a1 b1, |m4| <= 2**(AW+BW-36)
    localparam WH2 = AW + BW - 34;          // h2 = a*b >>> 34
    reg  signed [W1-1:0]    m1;             // multiplier registers (MREG)
    reg  signed [W2-1:0]    m2;
    reg  signed [W3-1:0]    m3;
    reg  signed [W4-1:0]    m4;
    reg  signed [WH1-1:0]   h1;             // cascade outputs (PREG of DSP2, DSP4)
    reg  signed [WH2-1:0]   h2;
    // The three post-adders are written as plain signed sums (Verilog sign-extends the operands
    // to the widest of them and the result; h1 and h2 keep the low WH1, WH2 bits, which is all p
    // needs: a*b >>> 34 fits WH2 bits). Written with explicit sign-extension slices instead,
    // yosys 0.23 finds none of the three PCIN cascades once a register in front of the product
    // is absorbed into AREG/BREG or the product shares its input with another, and takes each P
    // through fabric into the next C.
    /* verilator lint_off WIDTHEXPAND */
    wire signed [WD3-1:0]   d3 = m3 + h1;   // DSP3's post-adder (PCIN)
    /* verilator lint_on WIDTHEXPAND */
    reg         [16:0]      l3;             // d3[16:0]: product bits 17..33

    /* verilator lint_off UNUSEDSIGNAL */  // the bits below LO and the SH bits dropped
    wire        [XW-1:0]    hi;                  // a*b >>> 17, sign-extended to XW bits
    wire        [SW-1:0]    top = hi[LO-17 +: SW];
    wire        [SW-1:0]    c_x;                 // c sign-extended (or truncated) to SW bits
    wire        [SW-1:0]    sum = top + c_x;
    wire        [CW-1:0]    c_all = c;
    /* verilator lint_on UNUSEDSIGNAL */
    generate
        if (XW > HW) begin : hi_ext
            assign hi = {{XW-HW{h2[HW-18]}}, h2[HW-18:0], l3};
        end else begin : hi_fit
            assign hi = {h2[HW-18:0], l3};
        end
        if (CW >= SW) begin : c_cut
            assign c_x = c_all[SW-1:0];
        end else begin : c_ext
            assign c_x = {{SW-CW{c[CW-1]}}, c};
        end
    endgenerate

    always @(posedge clk) begin
        a_r <= a;
        b_r <= b;
        m1 <= a0 * b0;
        m2 <= a0 * b1;
        a1_d <= a1;
        b0_d <= b0;
        b1_d <= b1;
        /* verilator lint_off WIDTHEXPAND */
        /* verilator lint_off WIDTHTRUNC */
        h1 <= m2 + (m1 >>> 17);             // DSP2's post-adder (PCIN >> 17)
        /* verilator lint_on WIDTHTRUNC */
        /* verilator lint_on WIDTHEXPAND */
        m3 <= a1_d * b0_d;
        m4 <= a1_d * b1_d;
        /* verilator lint_off WIDTHEXPAND */
        /* verilator lint_off WIDTHTRUNC */
        h2 <= m4 + (d3 >>> 17);             // DSP4's post-adder (PCIN >> 17)
        /* verilator lint_on WIDTHTRUNC */
        /* verilator lint_on WIDTHEXPAND */
        l3 <= d3[16:0];
        p <= sum[SW-1:SH];
    end
endmodule

`resetall
