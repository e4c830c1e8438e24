// rc_coord_delay: a fixed delay of N clocks for W bits, no reset and no enable, so that
// synthesis maps it to shift-register LUTs (SRL16E/SRLC32E) instead of flip-flops.
//
// Latency N clocks (N = 0: a wire), throughput one word per clock; datapath only, it knows
// nothing of frames or lines. Its content after reset is undefined: use it for data whose
// validity travels in a reset register beside it.
module rc_coord_delay #(
    parameter W = 1,
    parameter N = 1
) (
    input  wire         clk,
    input  wire [W-1:0] d,
    output wire [W-1:0] q
);
    generate
        if (N == 0) begin : none
            assign q = d;
        end else if (N == 1) begin : one
            reg [W-1:0] r;
            always @(posedge clk) r <= d;
            assign q = r;
        end else begin : chain
            reg [N*W-1:0] r;     // newest at the bottom
            always @(posedge clk) r <= {r[(N-1)*W-1:0], d};
            assign q = r[(N-1)*W +: W];
        end
    endgenerate
endmodule
