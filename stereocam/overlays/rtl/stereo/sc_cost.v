// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * sc_cost: the matching costs (STEREO_CORE.md step 2), PARALLEL lanes a clock.
 *
 * A shift register holds the right census words of the last MAX_DISP pixels:
 * element k is `cr` of k slots ago (element 0 is `cr` itself), shifted at the
 * end of each slot's phase 3, when sc_census loads the next pixel's words.
 * So during a slot, with `cl` and `cr` those of pixel x (x: `x`, held for the
 * slot), element k is censusR(x - k). In phase g lane j takes element
 * d = PARALLEL * g + j: cost = popcount(cl ^ element d), or 62 when x < d,
 * in two pipeline stages (chunk counts, then their sum).
 *
 * Latency: group g of the slot's pixel is in `cost` (lane j at [6*j +: 6])
 * during the run clock 2 after its phase g, i.e. phase g + 2 (the next slot's
 * phase g - 2 for g >= 2). Throughput: one group of PARALLEL costs per run
 * clock. Every register is enabled by `run`. No reset (data only).
 * Parameters are checked at elaboration: MAX_DISP = 4 * PARALLEL, PARALLEL >= 1.
 */
module sc_cost #
(
    parameter MAX_DISP = 128,
    parameter PARALLEL = 32
)
(
    input  wire                    clk,
    input  wire                    run,
    input  wire [1:0]              phase,
    input  wire [10:0]             x,
    input  wire [61:0]             cl,
    input  wire [61:0]             cr,
    output reg  [PARALLEL*6-1:0]   cost
);

localparam NB = 62;
localparam NC = 21;  // chunks of 3 bits (the last has 2)
localparam NP = 11;  // pairs of chunks (the last has 1)
localparam [31:0] PAR32 = PARALLEL;
localparam [10:0] PAR = PAR32[10:0];

// parameter checks: an instance that breaks one fails to elaborate, naming the rule
generate
    if (MAX_DISP != 4 * PARALLEL || PARALLEL < 1) begin : g_check_groups
        sc_cost_parameter_MAX_DISP_must_be_4_times_PARALLEL groups_not_4();
    end
endgenerate

// right census words of the last MAX_DISP pixels: element k at [NB*k +: NB]; element 0 is cr
reg [NB*(MAX_DISP-1)-1:0] sr;
wire [NB*MAX_DISP-1:0] elems = {sr, cr};

always @(posedge clk) begin
    if (run && phase == 2'd3) begin
        sr <= elems[NB*(MAX_DISP-1)-1:0];
    end
end

genvar j, k;
generate
    for (j = 0; j < PARALLEL; j = j + 1) begin : g_lane
        // stage 1: the element of this phase, XOR, chunk counts and pair sums
        wire [NB-1:0] word = phase == 2'd0 ? elems[NB*j +: NB]
                           : phase == 2'd1 ? elems[NB*(PARALLEL + j) +: NB]
                           : phase == 2'd2 ? elems[NB*(2*PARALLEL + j) +: NB]
                           : elems[NB*(3*PARALLEL + j) +: NB];
        wire [NB+1:0] diff = {2'b00, cl ^ word};
        wire [2*NC-1:0] chunk;
        wire [3*NP-1:0] pair;
        for (k = 0; k < NC; k = k + 1) begin : g_chunk
            assign chunk[2*k +: 2] = {1'b0, diff[3*k]} + {1'b0, diff[3*k+1]} + {1'b0, diff[3*k+2]};
        end
        for (k = 0; k < NP; k = k + 1) begin : g_pair
            if (2 * k + 1 < NC) begin : g_two
                assign pair[3*k +: 3] = {1'b0, chunk[4*k +: 2]} + {1'b0, chunk[4*k+2 +: 2]};
            end else begin : g_one
                assign pair[3*k +: 3] = {1'b0, chunk[4*k +: 2]};
            end
        end
        // the disparity of this lane in this phase: x < d reaches left of the right image
        localparam [31:0] LANE32 = j;
        localparam [10:0] LANE = LANE32[10:0];
        wire [10:0] d = {9'd0, phase} * PAR + LANE;
        reg [3*NP-1:0] pair_reg;
        reg oob_reg;
        always @(posedge clk) begin
            if (run) begin
                pair_reg <= pair;
                oob_reg <= x < d;
            end
        end
        // stage 2: the sum of the pairs
        wire [3:0] q0 = {1'b0, pair_reg[0 +: 3]} + {1'b0, pair_reg[3 +: 3]};
        wire [3:0] q1 = {1'b0, pair_reg[6 +: 3]} + {1'b0, pair_reg[9 +: 3]};
        wire [3:0] q2 = {1'b0, pair_reg[12 +: 3]} + {1'b0, pair_reg[15 +: 3]};
        wire [3:0] q3 = {1'b0, pair_reg[18 +: 3]} + {1'b0, pair_reg[21 +: 3]};
        wire [3:0] q4 = {1'b0, pair_reg[24 +: 3]} + {1'b0, pair_reg[27 +: 3]};
        wire [4:0] h0 = {1'b0, q0} + {1'b0, q1};
        wire [4:0] h1 = {1'b0, q2} + {1'b0, q3};
        wire [4:0] h2 = {1'b0, q4} + {2'b00, pair_reg[30 +: 3]};
        wire [5:0] total = {1'b0, h0} + {1'b0, h1} + {1'b0, h2};
        always @(posedge clk) begin
            if (run) begin
                cost[6*j +: 6] <= oob_reg ? 6'd62 : total;
            end
        end
    end
endgenerate

endmodule

`resetall
