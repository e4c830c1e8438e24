// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_cost: the matching costs (STEREO_CORE.md step 2), PARALLEL lanes a clock.
 *
 * With `cl` and `cr` the census words of the slot's pixel x (`x`, held for the
 * slot; sc_census loads the next pixel's at the end of phase 3), lane j in
 * phase g computes the cost of d = PARALLEL * g + j: popcount(cl ^
 * censusR(x - d)), or 62 when x < d, in two pipeline stages (full adders and
 * 6:3 counters, then their sum). The right words reach the lanes through a
 * delay line (below): lane j reads it at a fixed stage.
 *
 * Latency: group g of the slot's pixel is in `cost` (lane j at [6*j +: 6])
 * during the run clock 2 after its phase g, i.e. phase g + 2 (the next slot's
 * phase g - 2 for g >= 2). Throughput: one group of PARALLEL costs per run
 * clock. Every register is enabled by `run`. Reset: the delay lines only (see there).
 * Parameters are checked at elaboration: MAX_DISP = 4 * PARALLEL, PARALLEL >= 1.
 */
module sc_cost #
(
    parameter MAX_DISP = 128,
    parameter PARALLEL = 32
)
(
    input  wire                    clk,
    input  wire                    rst,
    input  wire                    run,
    input  wire [1:0]              phase,
    input  wire [10:0]             x,
    input  wire [61:0]             cl,
    input  wire [61:0]             cr,
    output reg  [PARALLEL*6-1:0]   cost
);

localparam NB = 62;
localparam NC = 21;  // full adders on 3 bits each (the last has 2)
localparam [31:0] PAR32 = PARALLEL;
localparam [10:0] PAR = PAR32[10:0];

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (MAX_DISP != 4 * PARALLEL || PARALLEL < 1)
        sc_cost_parameter_MAX_DISP_must_be_4_times_PARALLEL groups_not_4();
    // verilator lint_on GENUNNAMED
endgenerate

// The right census words reach the lanes through a delay line instead of a multiplexer per lane.
// A stream gives, at run clock g of the slot of pixel x, the word of pixel x - PARALLEL g:
// cr itself at phase 0, else a tap of a shift register of the last 3 PARALLEL pixels' words
// (shifted once a slot, at the end of phase 3, when sc_census loads the next pixel's). The line
// delays the stream by one run clock a stage, and lane j reads stage 4 j: the stream of the slot
// j pixels back, so at phase g it holds the word of pixel x - j - PARALLEL g, its disparity's.
// (Four 62-bit words a lane to choose from, in a multiplexer, were 2k LUT; the line is flip-flops.
// Its stages have a reset so that no tool folds the untapped ones into shift-register LUTs.)
localparam HIST = 3 * PARALLEL;
reg [NB*HIST-1:0] hist;  // element k at [NB*k +: NB]: cr of pixel x - 1 - k
always @(posedge clk) begin
    if (rst) begin
        hist <= {NB*HIST{1'b0}};  // (reset, as the line below: flip-flops, not shift-register LUTs)
    end else if (run && phase == 2'd3) begin
        hist <= {hist[NB*(HIST-1)-1:0], cr};
    end
end
wire [NB-1:0] stream = phase == 2'd0 ? cr
                     : phase == 2'd1 ? hist[NB*(PARALLEL-1) +: NB]
                     : phase == 2'd2 ? hist[NB*(2*PARALLEL-1) +: NB]
                     : hist[NB*(3*PARALLEL-1) +: NB];
localparam LINE = 4 * (PARALLEL - 1);  // stages 1 .. LINE; stage 0 is the stream itself
reg [NB*LINE-1:0] line;  // stage i at [NB*(i-1) +: NB]
always @(posedge clk) begin
    if (rst) begin
        line <= {NB*LINE{1'b0}};
    end else if (run) begin
        line <= {line[NB*(LINE-1)-1:0], stream};
    end
end
wire [NB*(LINE+1)-1:0] stages = {line, stream};

// the lanes' disparities this run clock are PARALLEL * phase + j: x < PARALLEL * phase + j
// iff xs = x - PARALLEL * phase < j (one subtraction for all lanes, then compares with constants)
wire signed [12:0] xs = $signed({2'b00, x}) - $signed({2'b00, {9'd0, phase} * PAR});

// 6:3 counter: the number of ones among 6 bits
function [2:0] count6;
    input [5:0] v;
    begin
        count6 = {2'b00, v[0]} + {2'b00, v[1]} + {2'b00, v[2]} + {2'b00, v[3]} + {2'b00, v[4]}
               + {2'b00, v[5]};
    end
endfunction

genvar j, k;
generate
    for (j = 0; j < PARALLEL; j = j + 1) begin : g_lane
        localparam [31:0] LANE32 = j;
        localparam [12:0] LANE = LANE32[12:0];
        // stage 1: XOR, a full adder on each 3 bits (as logic, so the XORs merge into its LUTs),
        // then 6:3 counters on the sums (weight 1) and carries (weight 2)
        wire [NB-1:0] word = stages[NB*4*j +: NB];
        wire [NB:0] diff = {1'b0, cl ^ word};
        wire [NC-1:0] fa_s;
        wire [NC-1:0] fa_c;
        for (k = 0; k < NC; k = k + 1) begin : g_fa
            wire d0 = diff[3*k];
            wire d1 = diff[3*k+1];
            wire d2 = diff[3*k+2];
            assign fa_s[k] = d0 ^ d1 ^ d2;
            assign fa_c[k] = (d0 & d1) | (d2 & (d0 ^ d1));
        end
        wire [23:0] counts = {count6(fa_s[5:0]), count6(fa_s[11:6]), count6(fa_s[17:12]),
                              count6({3'b000, fa_s[20:18]}),
                              count6(fa_c[5:0]), count6(fa_c[11:6]), count6(fa_c[17:12]),
                              count6({3'b000, fa_c[20:18]})};
        reg [23:0] counts_reg;
        reg oob_reg;
        always @(posedge clk) begin
            if (run) begin
                counts_reg <= counts;
                oob_reg <= xs < $signed(LANE);
            end
        end
        // stage 2: the weighted sum of the counts
        wire [5:0] ones = {3'b000, counts_reg[21 +: 3]} + {3'b000, counts_reg[18 +: 3]}
                        + {3'b000, counts_reg[15 +: 3]} + {3'b000, counts_reg[12 +: 3]};
        wire [5:0] twos = {3'b000, counts_reg[9 +: 3]} + {3'b000, counts_reg[6 +: 3]}
                        + {3'b000, counts_reg[3 +: 3]} + {3'b000, counts_reg[0 +: 3]};
        wire [5:0] total = ones + {twos[4:0], 1'b0};
        always @(posedge clk) begin
            if (run) begin
                cost[6*j +: 6] <= oob_reg ? 6'd62 : total;
            end
        end
    end
endgenerate

endmodule

`resetall
