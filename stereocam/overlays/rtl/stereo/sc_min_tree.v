// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_min_tree: the minimum of N unsigned W-bit words, a binary tree of
 * two-input minima with STAGES register levels (the stereo core's path
 * minima: sc_path_left over MAX_DISP lanes, sc_path_up over PARALLEL).
 *
 * The tree has K = clog2(N) levels of minima (inputs past N count as all
 * ones, which never lower a minimum). With OUT_REG 1, registers sit after
 * tree level floor(K * s / STAGES) from the root, s = 0 .. STAGES - 1: the
 * root is registered. With OUT_REG 0 they sit after level
 * floor(K * s / (STAGES + 1)), s = 1 .. STAGES, and the root is logic after
 * the last register (for a caller that combines it with more); ROOT_LEVELS
 * > 0 (with STAGES 1) puts the register after level ROOT_LEVELS instead, so
 * a caller can leave the root's side shorter for its own logic.
 * Between registers, levels are taken two at a time where they can be: a
 * node then takes the least of its four grandchildren by six comparisons at
 * once and a choice, which is shorter than two levels of two-input minima
 * in a row (the lowest of each pair of levels, counted from the leaves' or
 * the register's side, is left to its parent).
 * Latency: STAGES enabled clocks (`en`: every register loads only when it
 * is 1, so the tree holds while it is 0). Throughput: one word set per
 * enabled clock. No reset (data only).
 * Parameters are checked at elaboration: N >= 2, W >= 1, 1 <= STAGES <= K
 * (STAGES < K with OUT_REG 0), OUT_REG 0 or 1.
 */
module sc_min_tree #
(
    parameter N = 32,
    parameter W = 8,
    parameter STAGES = 2,
    parameter OUT_REG = 1,
    parameter ROOT_LEVELS = 0
)
(
    input  wire           clk,
    input  wire           en,
    input  wire [N*W-1:0] in,
    output wire [W-1:0]   out
);

localparam K = $clog2(N);
localparam P = 1 << K;  // leaves

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (N < 2) sc_min_tree_parameter_N_must_be_at_least_2 n_too_small();
    if (W < 1) sc_min_tree_parameter_W_must_be_at_least_1 w_too_small();
    if (STAGES < 1 || STAGES > K || (OUT_REG == 0 && STAGES >= K))
        sc_min_tree_parameter_STAGES_must_be_1_to_clog2_N stages_out_of_range();
    if (OUT_REG != 0 && OUT_REG != 1) sc_min_tree_parameter_OUT_REG_must_be_0_or_1 out_reg_invalid();
    if (ROOT_LEVELS < 0 || (ROOT_LEVELS > 0 && (OUT_REG != 0 || STAGES != 1 || ROOT_LEVELS >= K)))
        sc_min_tree_parameter_ROOT_LEVELS_needs_OUT_REG_0_STAGES_1_below_K root_levels_invalid();
    // verilator lint_on GENUNNAMED
endgenerate

// tree level of heap node i (the root, node 1, is level 0)
function integer node_level;
    input integer i;
    integer v;
    begin
        node_level = 0;
        for (v = i; v > 1; v = v / 2) begin
            node_level = node_level + 1;
        end
    end
endfunction

// 1 when the nodes of level lev are registers
function integer level_registered;
    input integer lev;
    integer s;
    begin
        level_registered = 0;
        for (s = 0; s < STAGES; s = s + 1) begin
            if (OUT_REG != 0 && (K * s) / STAGES == lev) begin
                level_registered = 1;
            end
            if (OUT_REG == 0 && ROOT_LEVELS == 0 && (K * (s + 1)) / (STAGES + 1) == lev) begin
                level_registered = 1;
            end
        end
        if (ROOT_LEVELS > 0 && lev == ROOT_LEVELS) begin
            level_registered = 1;
        end
    end
endfunction

// 1 when the nodes of level lev take their four grandchildren (levels lev and lev + 1 as one): the
// upper of each pair of levels counted from the bottom of the run of levels between registers
function integer level_paired;
    input integer lev;
    integer bot;
    integer r;
    begin
        bot = K - 1;  // the lowest level of lev's run: above the next registered level, or K - 1
        for (r = K - 1; r > lev; r = r - 1) begin
            if (level_registered(r) != 0) begin
                bot = r - 1;
            end
        end
        level_paired = (lev < bot && (bot - lev) % 2 == 1) ? 1 : 0;
    end
endfunction

localparam SC_KEY_W = W;
`include "sc_least4.vh"


// heap-ordered nodes: node i is nodes[i]; the root is node 1, the leaves P .. 2P-1. An array of
// wires, so a simulator follows each node apart (one vector read and written by the whole tree is
// one signal to Icarus: every change would wake every node). Verilator still sees the array as one
// variable, so a loop (UNOPTFLAT, a note on its speed, not a fault).
/* verilator lint_off UNOPTFLAT */
wire [W-1:0] nodes [1:2*P-1];

genvar i;
generate
    for (i = P; i < 2 * P; i = i + 1) begin : g_leaf
        if (i - P < N) begin : g_in
            assign nodes[i] = in[(i-P)*W +: W];
        end else begin : g_pad
            assign nodes[i] = {W{1'b1}};
        end
    end
    for (i = 1; i < P; i = i + 1) begin : g_node
        wire [W-1:0] m;
        if (level_paired(node_level(i)) != 0) begin : g_four
            assign m = sc_min4(nodes[4*i], nodes[4*i+1], nodes[4*i+2], nodes[4*i+3]);
        end else begin : g_two
            wire [W-1:0] a = nodes[2*i];
            wire [W-1:0] b = nodes[2*i+1];
            assign m = (b < a) ? b : a;
        end
        if (level_registered(node_level(i)) != 0) begin : g_reg
            reg [W-1:0] m_reg;
            always @(posedge clk) begin
                if (en) begin
                    m_reg <= m;
                end
            end
            assign nodes[i] = m_reg;
        end else begin : g_wire
            assign nodes[i] = m;
        end
    end
endgenerate
/* verilator lint_on UNOPTFLAT */

assign out = nodes[1];

endmodule

`resetall
