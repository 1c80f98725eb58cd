pub mod bench;
pub mod client;
pub mod render;
pub mod serve;
pub mod up;
pub mod worker;
