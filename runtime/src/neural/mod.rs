pub mod hashgrid;
pub mod occupancy;
