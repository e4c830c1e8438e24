// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_cost: the matching costs (STEREO_CORE.md step 2), PARALLEL lanes a clock.
 *
 * A shift register holds the right census words of the last MAX_DISP pixels:
 * element k is `cr` of k slots ago (element 0 is `cr` itself), shifted at the
 * end of each slot's phase 3, when sc_census loads the next pixel's words.
 * So during a slot, with `cl` and `cr` those of pixel x (x: `x`, held for the
 * slot), element k is censusR(x - k). In phase g lane j takes element
 * d = PARALLEL * g + j: cost = popcount(cl ^ element d), or 62 when x < d,
 * in two pipeline stages (full adders and 6:3 counters, then their sum),
 * after the element itself is picked a run clock ahead.
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

// right census words of the last MAX_DISP pixels: element k at [NB*k +: NB]; element 0 is cr
reg [NB*(MAX_DISP-1)-1:0] sr;
wire [NB*MAX_DISP-1:0] elems = {sr, cr};

always @(posedge clk) begin
    if (run && phase == 2'd3) begin
        sr <= elems[NB*(MAX_DISP-1)-1:0];
    end
end

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
        // stage 0, a clock ahead: the element of the next phase's group (phase 3: the next slot's
        // group 0, element j - 1 before the shift; lane 0 takes cr itself at phase 0), registered
        // apart from the XOR so that neither makes the other's LUTs wider
        reg [NB-1:0] word_reg;
        always @(posedge clk) begin
            if (run) begin
                word_reg <= phase == 2'd0 ? elems[NB*(PARALLEL + j) +: NB]
                          : phase == 2'd1 ? elems[NB*(2*PARALLEL + j) +: NB]
                          : phase == 2'd2 ? elems[NB*(3*PARALLEL + j) +: NB]
                          : elems[NB*(j == 0 ? 0 : j - 1) +: NB];
            end
        end
        // stage 1: XOR, a full adder on each 3 bits (as logic, so the XORs merge into its LUTs),
        // then 6:3 counters on the sums (weight 1) and carries (weight 2)
        wire [NB-1:0] word = (j == 0 && phase == 2'd0) ? cr : word_reg;
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
