pub mod hashgrid;
