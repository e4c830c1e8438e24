// rc_coord_delay: a fixed delay of N clocks for W bits, no reset and no enable, so that
// synthesis maps it to shift-register LUTs (SRL16E/SRLC32E) instead of flip-flops.
//
// Latency N clocks (N = 0: a wire), throughput one word per clock; datapath only, it knows
// nothing of frames or lines. Its content after reset is undefined: use it for data whose
// validity travels in a reset register beside it. Parameters are checked at elaboration: W >= 1,
// N >= 0.
`include "prelude.vh"

module rc_coord_delay #(
    parameter W = 1,
    parameter N = 1
) (
    input  wire         clk,
    input  wire [W-1:0] d,
    output wire [W-1:0] q
);
    genvar i;
    // parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
    // unnamed block: it holds nothing in a build that passes)
    generate
        // verilator lint_off GENUNNAMED
        if (W < 1) rc_coord_delay_parameter_W_must_be_at_least_1 w_too_small();
        if (N < 0) rc_coord_delay_parameter_N_must_be_at_least_0 n_negative();
        // verilator lint_on GENUNNAMED
    endgenerate

    generate
        if (N == 0) begin : none
            assign q = d;
        end else if (N == 1) begin : one
            reg [W-1:0] r;
            always @(posedge clk) r <= d;
            assign q = r;
        end else if (N * W <= 64) begin : packed_chain
            // N * W bits fit one machine word: one shift a clock (newest at the bottom)
            reg [N*W-1:0] r;
            always @(posedge clk) r <= {r[(N-1)*W-1:0], d};
            assign q = r[(N-1)*W +: W];
        end else begin : chain
            // one register per stage (a simulator then copies each word once a clock, where one
            // N*W-bit vector shifted by W bits costs a shift of every word of it)
            for (i = 0; i < N; i = i + 1) begin : stage
                reg [W-1:0] r;
                if (i == 0) begin : first
                    always @(posedge clk) r <= d;
                end else begin : next
                    always @(posedge clk) r <= chain.stage[i-1].r;
                end
            end
            assign q = chain.stage[N-1].r;
        end
    endgenerate
endmodule

`resetall
