//! The `lbv` tool as its users meet it: its command line, the capture decoders (against sigrok and cantools), the
//! update file writer, and the bench flown over UDP by pymavlink and MAVProxy; and the firmware crates' module
//! structure. One test binary, so that these link once and the real-time ground-station tests run side by side.

mod cli;
mod cli_memory;
mod decode_can;
mod decode_can_cantools;
mod decode_i2c;
mod decode_i2c_sigrok;
mod hil_replay;
mod image;
mod mavproxy;
mod mavproxy_ftp;
mod mavsdk;
mod module_cycles;
mod support;
mod udp_flood;
mod udp_ftp;
mod udp_pymavlink;
