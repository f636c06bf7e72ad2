pub mod data;
pub mod train;
pub mod volume;
