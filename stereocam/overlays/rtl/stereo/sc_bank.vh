// sc_bank.vh: the stereo core's RAM banks: three rows live in each of its row-banked RAMs
// (records, right winners, checked codes), row y in bank y mod 3 at MAX_WIDTH words a bank.
// Included inside a module that has the parameter MAX_WIDTH.
function [31:0] bank_base;  // the first word of row y's bank
    input [10:0] y;
    begin
        bank_base = (y % 3) * MAX_WIDTH;
    end
endfunction
