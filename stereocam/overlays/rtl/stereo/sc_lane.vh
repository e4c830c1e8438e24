// The lane arithmetic of one step along a path (STEREO_CORE.md step 3), shared
// by sc_path_left and sc_path_up, which include it inside their module:
//   L(p, d) = C(p, d) + min(L(q, d), L(q, d - 1) + P1, L(q, d + 1) + P1, m + P2') - m
// in two parts: sc_lane_a, what depends on L(q) only, and sc_lane_step, which
// needs the minimum m = min_k L(q, k). A neighbour outside the range or masked
// is given as 255, which never lowers the minimum (L <= 62 + P2' <= 255).

// a = min(L(q, d), min(L(q, d - 1), L(q, d + 1)) + P1), 9 bits
function [8:0] sc_lane_a;
    input [7:0] l;
    input [7:0] lm;
    input [7:0] lp;
    input [7:0] pen1;
    reg [7:0] n;
    reg [8:0] np;
    begin
        n = lp < lm ? lp : lm;
        np = {1'b0, n} + {1'b0, pen1};
        sc_lane_a = np < {1'b0, l} ? np : {1'b0, l};
    end
endfunction

// C + min(a - m, P2') (a >= m: m is the least L(q, k), a one of them plus 0 or P1)
function [7:0] sc_lane_step;
    input [5:0] c;
    input [8:0] a;
    input [7:0] mn;
    input [7:0] pen2;
    reg [8:0] u;
    reg [7:0] b;
    begin
        u = a - {1'b0, mn};
        b = u < {1'b0, pen2} ? u[7:0] : pen2;
        sc_lane_step = {2'b00, c} + b;
    end
endfunction
