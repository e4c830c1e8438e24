// The lane arithmetic of one step along a path (STEREO_CORE.md step 3), shared
// by sc_path_left and sc_path_up, which include it inside their module:
//   L(p, d) = C(p, d) + min(L(q, d), L(q, d - 1) + P1, L(q, d + 1) + P1, m + P2') - m
// in two parts: sc_lane_a, what depends on L(q) only, and sc_lane_l, which
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

// L = C + min(a - m, P2') (a >= m: m is the least L(q, k), a one of them plus 0 or P1); C where
// the previous pixel is outside the image (`from_c`); 255 in a masked lane (`lane_in` 0). The two
// cases are made by the sum's operands (0 added for `from_c`; 63 + 192 for a masked lane), so that no
// choice follows the sum: the lane's L feeds registers and the next quarter's terms directly.
function [7:0] sc_lane_l;
    input [5:0] c;
    input [8:0] a;
    input [7:0] mn;
    input [7:0] pen2;
    input       from_c;   // the previous pixel is outside the image: L = C
    input       lane_in;  // the lane is below NUM_DISP
    reg [8:0] u;
    reg [7:0] b;
    reg [7:0] cc;
    begin
        u = a - {1'b0, mn};
        b = !lane_in ? 8'd192 : from_c ? 8'd0 : u < {1'b0, pen2} ? u[7:0] : pen2;
        cc = lane_in ? {2'b00, c} : 8'd63;
        sc_lane_l = cc + b;
    end
endfunction
