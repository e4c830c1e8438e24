// sc_least4.vh: which of four keys is the first of the least, by the six comparisons at once and a
// choice (shorter than two levels of two-input minima in a row), and the least of four values;
// sc_min_tree and sc_winners include it inside their module, after setting the localparam SC_KEY_W
// (the keys' width).
function [1:0] sc_least4;
    input [SC_KEY_W-1:0] a;
    input [SC_KEY_W-1:0] b;
    input [SC_KEY_W-1:0] c;
    input [SC_KEY_W-1:0] d;
    reg ab, ac, ad, bc, bd, cd;
    begin
        ab = b < a;
        ac = c < a;
        ad = d < a;
        bc = c < b;
        bd = d < b;
        cd = d < c;
        sc_least4 = (!ab && !ac && !ad) ? 2'd0 : (ab && !bc && !bd) ? 2'd1 : (ac && bc && !cd) ? 2'd2 : 2'd3;
    end
endfunction

// the least of four values
function [SC_KEY_W-1:0] sc_min4;
    input [SC_KEY_W-1:0] a;
    input [SC_KEY_W-1:0] b;
    input [SC_KEY_W-1:0] c;
    input [SC_KEY_W-1:0] d;
    begin
        case (sc_least4(a, b, c, d))
            2'd0: sc_min4 = a;
            2'd1: sc_min4 = b;
            2'd2: sc_min4 = c;
            default: sc_min4 = d;
        endcase
    end
endfunction
