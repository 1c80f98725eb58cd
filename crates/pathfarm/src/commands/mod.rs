pub mod bench;
pub mod client;
pub mod output;
pub mod render;
pub mod serve;
pub mod up;
pub mod worker;
