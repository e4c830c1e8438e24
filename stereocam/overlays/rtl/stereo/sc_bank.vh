// sc_bank.vh: the stereo core's RAM banks: three rows live in each of its row-banked RAMs
// (records, right winners, checked codes), row y in bank y mod 3 at MAX_WIDTH words a bank.
// Included inside a module that has the parameter MAX_WIDTH.
//
// y mod 3 without a divider (yosys builds `%` as one: 393 carry cells, 144 ns): 4 = 1 mod 3, so
// y mod 3 is the sum of y's base-4 digits mod 3; six 2-bit digits sum to at most 18, and a table
// of 19 entries gives the rest.
function [1:0] bank_of;
    input [10:0] y;
    reg [4:0] digits;
    begin
        digits = y[1:0] + y[3:2] + y[5:4] + y[7:6] + y[9:8] + {1'b0, y[10]};
        case (digits)
            5'd0, 5'd3, 5'd6, 5'd9, 5'd12, 5'd15, 5'd18: bank_of = 2'd0;
            5'd1, 5'd4, 5'd7, 5'd10, 5'd13, 5'd16: bank_of = 2'd1;
            default: bank_of = 2'd2;
        endcase
    end
endfunction

function [31:0] bank_base;  // the first word of row y's bank
    input [10:0] y;
    begin
        case (bank_of(y))
            2'd0: bank_base = 0;
            2'd1: bank_base = MAX_WIDTH;
            default: bank_base = 2 * MAX_WIDTH;
        endcase
    end
endfunction
