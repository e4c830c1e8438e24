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

function [31:0] base_of_bank;  // the first word of bank b
    input [1:0] b;
    begin
        case (b)
            2'd0: base_of_bank = 0;
            2'd1: base_of_bank = MAX_WIDTH;
            default: base_of_bank = 2 * MAX_WIDTH;
        endcase
    end
endfunction

function [31:0] bank_base;  // the first word of row y's bank
    input [10:0] y;
    begin
        bank_base = base_of_bank(bank_of(y));
    end
endfunction

// The bank k rows after (k mod 3 given) a row in bank b: (b + k) mod 3. From the scheduler's
// registered row bank, this is a LUT where bank_of on a computed row was an adder and a table
// behind the row arithmetic (a path over the period).
function [1:0] bank_plus;
    input [1:0] b;
    input [1:0] k;
    reg [2:0] s;
    begin
        s = b + k;
        bank_plus = (s >= 3'd3) ? s - 3'd3 : s[1:0];
    end
endfunction
