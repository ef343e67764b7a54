//! quadrature (to be written)
