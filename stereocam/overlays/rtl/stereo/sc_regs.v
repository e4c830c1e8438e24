// Language: Verilog 2005

`include "prelude.vh"

`include "stereo_spec.vh"

/*
 * sc_regs: the stereo core's register block (STEREO_CORE.md, "Registers"; offsets, fields and
 * limits from STEREO_MAP through stereo_spec.vh).
 *
 * AXI4-Lite slave, SC_ADDR_W-bit byte address, 32-bit data. AW and W are taken independently, in
 * either order, one of each held at a time; the write is done on the clock edge after both are
 * held (and B is free), byte by byte as WSTRB says. A read is decoded on the clock edge after
 * its address is held. Responses are always OKAY: an address outside the map reads 0, read-only
 * registers and bits ignore writes.
 * Shadow and active sets: WIDTH .. LR_TOL and CONTROL's LR_CHECK, SUBPIXEL and MEDIAN read back
 * what was written; CONTROL.APPLY (self-clearing, STATUS.APPLY_PENDING) makes them active on the
 * first clock between frames (`idle`; no frame starts while it is pending) if all are in range, else raises
 * FLAGS.CONFIG_ERROR and keeps the active set. FLAGS are sticky, cleared by writing 1 (a raise
 * wins over a clear on the same edge). FRAME_COUNT counts `frame_done`.
 * Reset: synchronous, active high: every register to its reset value, the active set to the
 * reset values (the spec's defaults).
 */
module sc_regs #
(
    parameter MAX_WIDTH = `SC_BUILD_DEPTH_MAX_WIDTH,
    parameter MAX_HEIGHT = `SC_BUILD_DEPTH_MAX_HEIGHT,
    parameter MAX_DISP = `SC_BUILD_DEPTH_MAX_DISP,
    parameter PARALLEL = `SC_BUILD_DEPTH_PARALLEL
)
(
    input  wire                  clk,
    input  wire                  rst,

    input  wire [`SC_ADDR_W-1:0] s_axil_awaddr,
    input  wire                  s_axil_awvalid,
    output reg                   s_axil_awready = 1'b0,
    input  wire [31:0]           s_axil_wdata,
    input  wire [3:0]            s_axil_wstrb,
    input  wire                  s_axil_wvalid,
    output reg                   s_axil_wready = 1'b0,
    output wire [1:0]            s_axil_bresp,
    output reg                   s_axil_bvalid = 1'b0,
    input  wire                  s_axil_bready,
    input  wire [`SC_ADDR_W-1:0] s_axil_araddr,
    input  wire                  s_axil_arvalid,
    output reg                   s_axil_arready = 1'b0,
    output reg  [31:0]           s_axil_rdata = 32'd0,
    output wire [1:0]            s_axil_rresp,
    output reg                   s_axil_rvalid = 1'b0,
    input  wire                  s_axil_rready,

    input  wire                  idle,             // between frames: an APPLY may latch now
    input  wire                  frame_done,
    input  wire                  set_size_error,
    input  wire                  busy,

    output reg                   enable = 1'b0,
    output wire                  apply_pending_out,
    output reg  [10:0]           width = 11'd`SC_WIDTH_RESET,
    output reg  [10:0]           height = 11'd`SC_HEIGHT_RESET,
    output reg  [7:0]            num_disp = 8'd`SC_NUM_DISP_RESET,
    output reg  [7:0]            p1 = 8'd`SC_P1_RESET,
    output reg  [7:0]            p2 = 8'd`SC_P2_RESET,
    output reg  [7:0]            p2_edge = 8'd`SC_P2_EDGE_RESET,
    output reg  [7:0]            edge_thresh = 8'd`SC_EDGE_THRESH_RESET,
    output reg  [7:0]            uniqueness = 8'd`SC_UNIQUENESS_RESET,
    output reg  [3:0]            lr_tol = 4'd`SC_LR_TOL_RESET,
    output reg                   lr_check = 1'b0,
    output reg                   subpixel = 1'b0,
    output reg                   median = 1'b0
);

localparam [31:0] CONTROL_RESET = `SC_CONTROL_RESET;
assign s_axil_bresp = 2'b00;
assign apply_pending_out = apply_pending;
assign s_axil_rresp = 2'b00;

// shadow set (read back), as written
reg [15:0] sh_width, sh_height;
reg [7:0]  sh_num_disp, sh_p1, sh_p2, sh_p2_edge, sh_edge, sh_uniq;
reg [3:0]  sh_lr_tol;
reg        sh_lr, sh_sub, sh_med;
reg        apply_pending = 1'b0;
reg        config_error = 1'b0, size_error = 1'b0;
reg [31:0] frame_count = 32'd0;

// the write channel: hold AW and W
reg                  aw_held = 1'b0, w_held = 1'b0;
reg [`SC_ADDR_W-1:0] aw_addr;
reg [31:0]           w_data;
reg [3:0]            w_strb;

function [31:0] merge;
    input [31:0] old;
    input [31:0] data;
    input [3:0]  strb;
    integer b;
    begin
        for (b = 0; b < 4; b = b + 1) merge[8*b +: 8] = strb[b] ? data[8*b +: 8] : old[8*b +: 8];
    end
endfunction

function [31:0] control_word;  // CONTROL as read
    input dummy;
    begin
        control_word = 32'd0;
        control_word[`SC_CONTROL_ENABLE] = enable;
        control_word[`SC_CONTROL_LR_CHECK] = sh_lr;
        control_word[`SC_CONTROL_SUBPIXEL] = sh_sub;
        control_word[`SC_CONTROL_MEDIAN] = sh_med;
        control_word[`SC_CONTROL_APPLY] = apply_pending;
    end
endfunction

wire shadow_ok =
    sh_width >= `SC_MIN_WIDTH && sh_width <= MAX_WIDTH
    && sh_height >= `SC_MIN_HEIGHT && sh_height <= MAX_HEIGHT
    && sh_num_disp >= PARALLEL && sh_num_disp <= MAX_DISP && (sh_num_disp % PARALLEL) == 0
    && sh_p1 <= `SC_P1_MAX && sh_p2 <= `SC_P2_MAX && sh_p2_edge <= `SC_P2_EDGE_MAX
    && sh_p1 <= sh_p2_edge && sh_p2_edge <= sh_p2;

wire do_write = aw_held && w_held && !s_axil_bvalid;
wire [31:0] wword = merge(32'd0, w_data, w_strb);

always @(posedge clk) begin
    if (rst) begin
        s_axil_awready <= 1'b0;
        s_axil_wready <= 1'b0;
        s_axil_bvalid <= 1'b0;
        aw_held <= 1'b0;
        w_held <= 1'b0;
        enable <= CONTROL_RESET[`SC_CONTROL_ENABLE];
        sh_lr <= CONTROL_RESET[`SC_CONTROL_LR_CHECK];
        sh_sub <= CONTROL_RESET[`SC_CONTROL_SUBPIXEL];
        sh_med <= CONTROL_RESET[`SC_CONTROL_MEDIAN];
        lr_check <= CONTROL_RESET[`SC_CONTROL_LR_CHECK];
        subpixel <= CONTROL_RESET[`SC_CONTROL_SUBPIXEL];
        median <= CONTROL_RESET[`SC_CONTROL_MEDIAN];
        sh_width <= `SC_WIDTH_RESET;
        sh_height <= `SC_HEIGHT_RESET;
        sh_num_disp <= `SC_NUM_DISP_RESET;
        sh_p1 <= `SC_P1_RESET;
        sh_p2 <= `SC_P2_RESET;
        sh_p2_edge <= `SC_P2_EDGE_RESET;
        sh_edge <= `SC_EDGE_THRESH_RESET;
        sh_uniq <= `SC_UNIQUENESS_RESET;
        sh_lr_tol <= `SC_LR_TOL_RESET;
        width <= `SC_WIDTH_RESET;
        height <= `SC_HEIGHT_RESET;
        num_disp <= `SC_NUM_DISP_RESET;
        p1 <= `SC_P1_RESET;
        p2 <= `SC_P2_RESET;
        p2_edge <= `SC_P2_EDGE_RESET;
        edge_thresh <= `SC_EDGE_THRESH_RESET;
        uniqueness <= `SC_UNIQUENESS_RESET;
        lr_tol <= `SC_LR_TOL_RESET;
        apply_pending <= 1'b0;
        config_error <= 1'b0;
        size_error <= 1'b0;
        frame_count <= 32'd0;
    end else begin
        // channel handshakes
        s_axil_awready <= !aw_held && !s_axil_awready;
        s_axil_wready <= !w_held && !s_axil_wready;
        if (s_axil_awvalid && s_axil_awready) begin
            aw_held <= 1'b1;
            aw_addr <= s_axil_awaddr;
            s_axil_awready <= 1'b0;
        end
        if (s_axil_wvalid && s_axil_wready) begin
            w_held <= 1'b1;
            w_data <= s_axil_wdata;
            w_strb <= s_axil_wstrb;
            s_axil_wready <= 1'b0;
        end
        if (s_axil_bvalid && s_axil_bready) s_axil_bvalid <= 1'b0;
        if (do_write) begin
            aw_held <= 1'b0;
            w_held <= 1'b0;
            s_axil_bvalid <= 1'b1;
            case ({aw_addr[`SC_ADDR_W-1:2], 2'b00})
                `SC_REG_CONTROL: begin
                    if (w_strb[0]) begin
                        enable <= wword[`SC_CONTROL_ENABLE];
                        sh_lr <= wword[`SC_CONTROL_LR_CHECK];
                        sh_sub <= wword[`SC_CONTROL_SUBPIXEL];
                        sh_med <= wword[`SC_CONTROL_MEDIAN];
                        if (wword[`SC_CONTROL_APPLY]) apply_pending <= 1'b1;
                    end
                end
                `SC_REG_FLAGS: begin
                    if (wword[`SC_FLAGS_SIZE_ERROR]) size_error <= 1'b0;
                    if (wword[`SC_FLAGS_CONFIG_ERROR]) config_error <= 1'b0;
                end
                `SC_REG_WIDTH: sh_width <= merge({16'd0, sh_width}, w_data, w_strb);
                `SC_REG_HEIGHT: sh_height <= merge({16'd0, sh_height}, w_data, w_strb);
                `SC_REG_NUM_DISP: if (w_strb[0]) sh_num_disp <= w_data[7:0];
                `SC_REG_P1: if (w_strb[0]) sh_p1 <= w_data[7:0];
                `SC_REG_P2: if (w_strb[0]) sh_p2 <= w_data[7:0];
                `SC_REG_P2_EDGE: if (w_strb[0]) sh_p2_edge <= w_data[7:0];
                `SC_REG_EDGE_THRESH: if (w_strb[0]) sh_edge <= w_data[7:0];
                `SC_REG_UNIQUENESS: if (w_strb[0]) sh_uniq <= w_data[7:0];
                `SC_REG_LR_TOL: if (w_strb[0]) sh_lr_tol <= w_data[3:0];
                default: ;
            endcase
        end
        // read channel
        if (s_axil_rvalid && s_axil_rready) s_axil_rvalid <= 1'b0;
        s_axil_arready <= !s_axil_rvalid && !s_axil_arready && !(s_axil_arvalid && s_axil_arready);
        if (s_axil_arvalid && s_axil_arready) begin
            s_axil_arready <= 1'b0;
            s_axil_rvalid <= 1'b1;
            case ({s_axil_araddr[`SC_ADDR_W-1:2], 2'b00})
                `SC_REG_ID: s_axil_rdata <= `SC_CORE_ID;
                `SC_REG_VERSION: s_axil_rdata <= `SC_CORE_VERSION;
                `SC_REG_MAX_WIDTH: s_axil_rdata <= MAX_WIDTH;
                `SC_REG_MAX_HEIGHT: s_axil_rdata <= MAX_HEIGHT;
                `SC_REG_MAX_DISP: s_axil_rdata <= MAX_DISP;
                `SC_REG_PARALLEL: s_axil_rdata <= PARALLEL;
                `SC_REG_CONTROL: s_axil_rdata <= control_word(1'b0);
                `SC_REG_STATUS: s_axil_rdata <= (busy << `SC_STATUS_BUSY)
                                                | (apply_pending << `SC_STATUS_APPLY_PENDING);
                `SC_REG_FLAGS: s_axil_rdata <= (size_error << `SC_FLAGS_SIZE_ERROR)
                                               | (config_error << `SC_FLAGS_CONFIG_ERROR);
                `SC_REG_FRAME_COUNT: s_axil_rdata <= frame_count;
                `SC_REG_WIDTH: s_axil_rdata <= sh_width;
                `SC_REG_HEIGHT: s_axil_rdata <= sh_height;
                `SC_REG_NUM_DISP: s_axil_rdata <= sh_num_disp;
                `SC_REG_P1: s_axil_rdata <= sh_p1;
                `SC_REG_P2: s_axil_rdata <= sh_p2;
                `SC_REG_P2_EDGE: s_axil_rdata <= sh_p2_edge;
                `SC_REG_EDGE_THRESH: s_axil_rdata <= sh_edge;
                `SC_REG_UNIQUENESS: s_axil_rdata <= sh_uniq;
                `SC_REG_LR_TOL: s_axil_rdata <= sh_lr_tol;
                default: s_axil_rdata <= 32'd0;
            endcase
        end
        // the latch between frames
        if (idle && apply_pending && !do_write) begin
            apply_pending <= 1'b0;
            if (shadow_ok) begin
                width <= sh_width[10:0];
                height <= sh_height[10:0];
                num_disp <= sh_num_disp;
                p1 <= sh_p1;
                p2 <= sh_p2;
                p2_edge <= sh_p2_edge;
                edge_thresh <= sh_edge;
                uniqueness <= sh_uniq;
                lr_tol <= sh_lr_tol;
                lr_check <= sh_lr;
                subpixel <= sh_sub;
                median <= sh_med;
            end else begin
                config_error <= 1'b1;
            end
        end
        if (set_size_error) size_error <= 1'b1;
        if (frame_done) frame_count <= frame_count + 32'd1;
    end
end

endmodule

`resetall
