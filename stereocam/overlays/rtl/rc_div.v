// rc_div: pipelined non-restoring divider, one quotient bit per stage, several
// numerators sharing one divisor.
//
// For each lane l: quo_l = floor(num_l * 2**SH / den), exact, for
// 0 <= num_l < den * 2**(QB - SH) and den > 0 (then quo_l < 2**QB). Other inputs give
// some value and nothing else happens (no trap, no stall): the caller masks them.
//
// Latency QB clocks (num/den sampled on one clock edge, the quotient of that sample is on
// quo QB - 1 edges later, i.e. QB register stages), throughput one division per lane per
// clock, no handshake, no reset (pure datapath: it knows nothing of frames or lines).
//
// Stage j (1..QB) holds one partial remainder P per lane, -den <= P < den, in DW + 1
// signed bits, and the divisor. P0 = num >> (QB - SH) (< den), then
//   P_j = 2 P_(j-1) + b_j - den   if P_(j-1) >= 0
//   P_j = 2 P_(j-1) + b_j + den   if P_(j-1) <  0
// with b_j the next bit of num * 2**SH, and quotient bit QB - j is (P_j >= 0). Each stage
// is one DW + 1 bit add/subtract (one LUT per bit on a carry chain, no restoring mux);
// the result fits DW + 1 bits, so the arithmetic is modulo 2**(DW+1). The quotient bits
// already found only travel down the stages (shift-register chains: SRLs on Xilinx).
// Parameters are checked at elaboration: LANES, QB, DW >= 1, 0 <= SH <= QB, NW > QB - SH.
`include "prelude.vh"

module rc_div #(
    parameter LANES = 2,   // numerators sharing the divisor
    parameter NW = 48,     // numerator width (unsigned magnitude)
    parameter DW = 47,     // divisor width (unsigned)
    parameter QB = 33,     // quotient bits (= pipeline stages)
    parameter SH = 31      // numerator scale: quo = floor(num * 2**SH / den); SH <= QB
) (
    input  wire                  clk,
    input  wire [LANES*NW-1:0]   num,
    input  wire [DW-1:0]         den,
    output wire [LANES*QB-1:0]   quo
);
    localparam RW = DW + 1;          // signed partial remainder
    localparam IB = QB - SH;         // integer quotient bits: numerator bits fed in by stages 1..IB
    localparam IBW = (IB > 0) ? IB : 1;

    // parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
    // unnamed block: it holds nothing in a build that passes)
    generate
        // verilator lint_off GENUNNAMED
        if (LANES < 1) rc_div_parameter_LANES_must_be_at_least_1 lanes_too_small();
        if (QB < 1) rc_div_parameter_QB_must_be_at_least_1 qb_too_small();
        if (SH < 0 || SH > QB) rc_div_parameter_SH_must_be_0_to_QB sh_invalid();
        if (NW <= QB - SH) rc_div_parameter_NW_must_exceed_QB_minus_SH nw_too_small();
        if (DW < 1) rc_div_parameter_DW_must_be_at_least_1 dw_too_small();
        // verilator lint_on GENUNNAMED
    endgenerate

    genvar l, j;
    generate
        for (j = 1; j <= QB; j = j + 1) begin : stage
            // Stage j: registers den_r (j < QB), and per lane rem_r (P_j, j < QB), nlo_r (the
            // numerator bits still to be fed in, j < IB) and q_r (quotient bits QB-1 .. QB-j).
            // Each stage reads the one before by name, so a simulator wakes only that one.
            wire [DW-1:0] den_in;
            if (j == 1) begin : from_in
                assign den_in = den;
            end else begin : from_prev
                assign den_in = stage[j-1].keep_den.den_r;
            end
            if (j < QB) begin : keep_den
                reg [DW-1:0] den_r;
                always @(posedge clk) den_r <= den_in;
            end

            for (l = 0; l < LANES; l = l + 1) begin : lane
                wire [RW-1:0]  rem_in;     // P_(j-1)
                wire [IBW-1:0] nlo_in;
                if (j == 1) begin : from_in
                    // P_0 = num >> IB < den: it fits the divisor's width.
                    /* verilator lint_off UNUSEDSIGNAL */
                    wire [NW-IB-1:0] top = num[l*NW + IB +: NW - IB];
                    /* verilator lint_on UNUSEDSIGNAL */
                    if (NW - IB >= DW) begin : cut
                        assign rem_in = {1'b0, top[DW-1:0]};
                    end else begin : ext
                        assign rem_in = {{RW-NW+IB{1'b0}}, top};
                    end
                    assign nlo_in = num[l*NW +: IBW];
                end else begin : from_prev
                    assign rem_in = stage[j-1].lane[l].keep_rem.rem_r;
                    if (j <= IB) begin : fed
                        assign nlo_in = stage[j-1].lane[l].keep_nlo.nlo_r;
                    end else begin : done
                        assign nlo_in = {IBW{1'b0}};
                    end
                end
                // The stage's adder and its registers in one clocked block, the sum a variable of
                // it: a simulator then keeps the sum in a machine register instead of storing it
                // in the model and reading it back (Icarus also runs one block faster than the same
                // logic in continuous assignments; synthesis is the same).
                wire          neg = (j == 1) ? 1'b0 : rem_in[RW-1];  // P_(j-1) < 0: add the divisor
                wire          b = (j <= IB) ? nlo_in[IBW-1] : 1'b0;  // the next bit of the dividend num * 2**SH
                reg [j-1:0]   q_r;      // the quotient bits found by stages 1 .. j, newest at the bottom
                wire [j-1:0]  q_in;     // the bits found by stages 1 .. j-1, and a dummy bit for j = 1
                if (j == 1) begin : q_first
                    assign q_in = 1'b0;
                end else begin : q_next
                    assign q_in = {stage[j-1].lane[l].q_r, 1'b0};
                end
                if (j < QB) begin : keep_rem
                    reg [RW-1:0] rem_r;
                    always @(posedge clk) begin : step
                        // {2 P_(j-1) + b, 1} + {+-den, carry}: one adder for +den and -den
                        reg [RW:0]  sum;
                        reg [j-1:0] qb;   // the new quotient bit, at the bottom
                        sum = {rem_in[RW-2:0], b, 1'b1} + {{1'b0, den_in} ^ {RW{~neg}}, ~neg};
                        qb = {j{1'b0}};
                        qb[0] = ~sum[RW];
                        rem_r <= sum[RW:1];
                        q_r <= q_in | qb;
                    end
                end else begin : last
                    always @(posedge clk) begin : step
                        reg [RW:0]  sum;
                        reg [j-1:0] qb;
                        sum = {rem_in[RW-2:0], b, 1'b1} + {{1'b0, den_in} ^ {RW{~neg}}, ~neg};
                        qb = {j{1'b0}};
                        qb[0] = ~sum[RW];
                        q_r <= q_in | qb;
                    end
                end
                if (j < IB) begin : keep_nlo
                    reg [IBW-1:0] nlo_r;
                    always @(posedge clk) nlo_r <= nlo_in << 1;
                end
            end
        end
        for (l = 0; l < LANES; l = l + 1) begin : out
            assign quo[l*QB +: QB] = stage[QB].lane[l].q_r;
        end
    endgenerate
endmodule

`resetall
